"""Damaged images and text files given to every tool that reads them (the "one image reader").

Each case is held to the contract of ``tests/test_cli_matrix.py`` (exit code 1, one line naming
the file and what is wrong, no traceback, nothing written), run in this process: a truncated
JPEG colour frame (decoders would fill its missing rows with grey and go on), a frame whose
content is another format than its name says (WebP named ``.png``: decoded by content), a truncated
depth PNG (libpng would print its own line first), a label PNG holding a value that is no
class id (7), and a Latin-1 byte in a text file (the line names its line number).
"""

# ruff: noqa: F811  (world: the shared fixture, imported, then a parameter of the tests)

from __future__ import annotations

from pathlib import Path

import cv2
import pytest
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from test_cli_matrix import (  # noqa: F401  (world: the fixture of the shared inputs)
    EXPORT,
    TRAIN,
    Case,
    case,
    check_case,
    nth,
    over,
    seq_copy,
    world,
    write,
)


def truncated_jpeg(folder: str, k: int):
    """Frame ``k`` of ``folder`` replaced by the first half of its JPEG encoding."""

    def change(seq: Path) -> None:
        path = nth(folder, k)(seq)
        ok, data = cv2.imencode(".jpg", cv2.imread(str(path), cv2.IMREAD_COLOR))
        path.write_bytes(data.tobytes()[: len(data) // 2])

    return change


def encoded_as(folder: str, k: int, ext: str):
    """Frame ``k`` of ``folder`` replaced by its whole encoding in another format (``.webp``,
    ``.jpg``) under its own name (``.png``)."""

    def change(seq: Path) -> None:
        path = nth(folder, k)(seq)
        ok, data = cv2.imencode(ext, cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
        path.write_bytes(data.tobytes())

    return change


def truncated_png(folder: str, k: int):
    def change(seq: Path) -> None:
        path = nth(folder, k)(seq)
        path.write_bytes(path.read_bytes()[:-30])

    return change


def png_named_jpg(k: int):
    """Colour frame ``k`` (a PNG) renamed ``.jpg`` in ``rgb/`` and ``rgb.txt``."""

    def change(seq: Path) -> None:
        path = nth("rgb", k)(seq)
        path.rename(path.with_suffix(".jpg"))
        listed = seq / "rgb.txt"
        listed.write_text(listed.read_text().replace(f"rgb/{path.name}", f"rgb/{path.stem}.jpg"))

    return change


def sixteen_bit_colour(k: int):
    """Colour frame ``k`` rewritten as a 16-bit RGB PNG (the same picture, scaled by 257)."""

    def change(seq: Path) -> None:
        path = nth("rgb", k)(seq)
        cv2.imwrite(str(path), cv2.imread(str(path), cv2.IMREAD_COLOR).astype("uint16") * 257)

    return change


def label_seven(k: int):
    def change(seq: Path) -> None:
        path = nth("labels", k)(seq)
        labels = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        labels[:4, :4] = 7
        cv2.imwrite(str(path), labels)

    return change


def latin1_groundtruth(seq: Path) -> None:
    path = seq / "groundtruth.txt"
    lines = path.read_bytes().splitlines(keepends=True)
    lines[4] = b"# recorded in the caf\xe9\n"
    path.write_bytes(b"".join(lines))


SLAM_S = "sequence.path={s} out_dir={tmp}/out progress=false"
TRUNCATED = "truncated JPEG: its image data ends without an end-of-image marker (FFD9)"
NOT_A_CLASS = "label values 7 are not class ids; expected 0..3"
WEBP = "its content is a WebP image, not the PNG its name says"
PNG_AS_JPEG = "its content is a PNG image, not the JPEG its name says"
SIXTEEN = "a 16-bit PNG (a depth image?); expected an 8-bit colour image (PNG or JPEG)"
DEMO_S = "--out {tmp}/demo --experiment ci --sequence {s} --quiet"
CASES = [
    case("slam-png-named-jpg", "uss-slam", SLAM_S, 1, "{s}/rgb/", PNG_AS_JPEG,
         setup=(seq_copy(png_named_jpg(3)),)),
    case("eval-png-named-jpg", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/rgb/", PNG_AS_JPEG, setup=(seq_copy(png_named_jpg(1)),)),
    case("train-target-png-named-jpg", "uss-train", over(TRAIN, "data.target.roots=[{s}]"), 1,
         "data.target.roots=", "rgb/", PNG_AS_JPEG, setup=(seq_copy(png_named_jpg(2)),)),
    case("train-val-png-named-jpg", "uss-train", over(TRAIN, "data.val.roots=[{s}]"), 1,
         "data.val.roots=", "rgb/", PNG_AS_JPEG, setup=(seq_copy(png_named_jpg(2)),)),
    case("demo-sequence-png-named-jpg", "uss-demo", DEMO_S, 1, "rgb/", PNG_AS_JPEG,
         setup=(seq_copy(png_named_jpg(2)),)),
    case("slam-16-bit-colour-frame", "uss-slam", SLAM_S, 1, "{s}/rgb/", SIXTEEN,
         setup=(seq_copy(sixteen_bit_colour(3)),)),
    case("eval-16-bit-colour-frame", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/rgb/", SIXTEEN, setup=(seq_copy(sixteen_bit_colour(1)),)),
    case("train-target-16-bit-colour-frame", "uss-train",
         over(TRAIN, "data.target.roots=[{s}]"), 1, "data.target.roots=", "rgb/", SIXTEEN,
         setup=(seq_copy(sixteen_bit_colour(2)),)),
    case("train-val-16-bit-colour-frame", "uss-train", over(TRAIN, "data.val.roots=[{s}]"), 1,
         "data.val.roots=", "rgb/", SIXTEEN, setup=(seq_copy(sixteen_bit_colour(2)),)),
    case("demo-sequence-16-bit-colour-frame", "uss-demo", DEMO_S, 1, "rgb/", SIXTEEN,
         setup=(seq_copy(sixteen_bit_colour(2)),)),
    case("slam-webp-named-png", "uss-slam", SLAM_S, 1, "{s}/rgb/", WEBP,
         setup=(seq_copy(encoded_as("rgb", 3, ".webp")),)),
    case("slam-jpeg-labels-named-png", "uss-slam",
         f"{SLAM_S} segmenter=labels filters=[semantic]", 1, "{s}/labels/",
         "its content is a JPEG image, not the PNG its name says",
         setup=(seq_copy(encoded_as("labels", 2, ".jpg")),)),
    case("vocab-webp-named-png", "uss-vocab",
         "build {s} --out {tmp}/v.txt -k 3 -L 2 --stride 1", 1, "{s}/rgb/", WEBP,
         setup=(seq_copy(encoded_as("rgb", 3, ".webp")),)),
    case("eval-webp-named-png", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/rgb/", WEBP, setup=(seq_copy(encoded_as("rgb", 1, ".webp")),)),
    case("export-calibration-webp-named-png", "uss-export",
         f"{EXPORT} int8=true calibration.root={{s}} calibration.frames=2", 1,
         "calibration.root={s}: rgb/", WEBP, setup=(seq_copy(encoded_as("rgb", 0, ".webp")),)),
    case("slam-truncated-jpeg-frame", "uss-slam", SLAM_S, 1, "{s}/rgb/", TRUNCATED,
         setup=(seq_copy(truncated_jpeg("rgb", 3)),)),
    case("slam-truncated-depth-png", "uss-slam", SLAM_S, 1, "{s}/depth/",
         "truncated PNG", setup=(seq_copy(truncated_png("depth", 2)),)),
    case("slam-labels-segmenter-class-7", "uss-slam",
         f"{SLAM_S} segmenter=labels filters=[semantic]", 1, "{s}/labels/", NOT_A_CLASS,
         setup=(seq_copy(label_seven(2)),)),
    case("slam-latin1-groundtruth", "uss-slam", SLAM_S, 1, "{s}/groundtruth.txt:5: not a text "
         "file: byte 0xe9 at column 22 is not UTF-8", setup=(seq_copy(latin1_groundtruth),)),
    case("vocab-truncated-jpeg-frame", "uss-vocab",
         "build {s} --out {tmp}/v.txt -k 3 -L 2 --stride 1", 1, "{s}/rgb/", TRUNCATED,
         setup=(seq_copy(truncated_jpeg("rgb", 3)),)),
    case("eval-truncated-jpeg-frame", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/rgb/", TRUNCATED, setup=(seq_copy(truncated_jpeg("rgb", 1)),)),
    case("eval-label-class-7", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/labels/", NOT_A_CLASS, setup=(seq_copy(label_seven(1)),)),
    case("export-calibration-truncated-jpeg", "uss-export",
         f"{EXPORT} int8=true calibration.root={{s}} calibration.frames=2", 1,
         "calibration.root={s}: rgb/",
         TRUNCATED, setup=(seq_copy(truncated_jpeg("rgb", 0)),)),
    case("traj-latin1-groundtruth", "uss-traj", "ate {s}/groundtruth.txt {gt}", 1,
         "{s}/groundtruth.txt:5: not a text file: byte 0xe9 at column 22 is not UTF-8",
         setup=(seq_copy(latin1_groundtruth),)),
]  # fmt: skip


@pytest.mark.parametrize("bad", [pytest.param(c, id=c.id, marks=c.marks) for c in CASES])
def test_damaged_input(
    bad: Case, world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd
) -> None:
    try:
        check_case(bad, world, tmp_path, monkeypatch, capfd)
    finally:
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()

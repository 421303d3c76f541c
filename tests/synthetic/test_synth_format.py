"""Synthetic output follows the TUM RGB-D and PASCAL VOC file formats exactly."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from uss_slam.core.classes import NUM_CLASSES, voc_palette
from uss_slam.core.tum_io import (
    TUM_CAMERAS,
    CameraIntrinsics,
    associate,
    read_file_list,
    read_trajectory,
)
from uss_slam.synthetic.styles import DEPTH_NOISE_K
from uss_slam.synthetic.voc import void_width

STAMP = re.compile(r"^\d{10}\.\d{6}$")


def _independent_list(path: Path) -> list[tuple[float, str]]:
    """A minimal reader following TUM's rules (not the project's): '#' comments, two fields."""
    rows = []
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        stamp, name = line.split(" ")
        assert STAMP.match(stamp), line
        rows.append((float(stamp), name))
    return rows


def _independent_trajectory(path: Path) -> np.ndarray:
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            continue
        fields = line.split(" ")
        assert len(fields) == 8, line
        rows.append([float(f) for f in fields])
    return np.array(rows)


@pytest.fixture(scope="module")
def sequence(synthetic_sequence) -> Path:
    return synthetic_sequence(frames=12, size=(160, 120))


def test_layout_and_image_types(sequence: Path) -> None:
    assert {p.name for p in sequence.iterdir()} >= {
        "rgb",
        "depth",
        "labels",
        "rgb.txt",
        "depth.txt",
        "groundtruth.txt",
        "intrinsics.yaml",
    }
    rgb = _independent_list(sequence / "rgb.txt")
    depth = _independent_list(sequence / "depth.txt")
    assert len(rgb) == len(depth) == 12
    for stamp, name in rgb:
        assert name == f"rgb/{stamp:.6f}.png"
        img = cv2.imread(str(sequence / name), cv2.IMREAD_UNCHANGED)
        assert img.shape == (120, 160, 3) and img.dtype == np.uint8
        labels = cv2.imread(str(sequence / "labels" / Path(name).name), cv2.IMREAD_UNCHANGED)
        assert labels.shape == (120, 160) and labels.dtype == np.uint8
        assert labels.max() < NUM_CLASSES
    for stamp, name in depth:
        assert name == f"depth/{stamp:.6f}.png"
        d = cv2.imread(str(sequence / name), cv2.IMREAD_UNCHANGED)
        assert d.shape == (120, 160) and d.dtype == np.uint16
        # 5000 units per metre; nothing beyond the 4.5 m range cut; holes (depth edges of the
        # people walking close in front, no data below 0.4 m) cover at most a quarter
        assert d.max() <= 4.5 * 5000 and (d > 0).mean() > 0.75
    assert sorted(p.name for p in (sequence / "rgb").iterdir()) == sorted(
        p.name for p in (sequence / "labels").iterdir()
    )


def test_lists_agree_with_project_reader(sequence: Path) -> None:
    for name in ("rgb.txt", "depth.txt"):
        ours = read_file_list(sequence / name)
        mine = _independent_list(sequence / name)
        assert list(ours.files) == [n for _, n in mine]
        np.testing.assert_array_equal(ours.stamps, [s for s, _ in mine])
        assert np.all(np.diff(ours.stamps) > 0)
    gt = read_trajectory(sequence / "groundtruth.txt")
    raw = _independent_trajectory(sequence / "groundtruth.txt")
    np.testing.assert_allclose(gt.stamps, raw[:, 0])
    np.testing.assert_allclose(gt.positions, raw[:, 1:4])
    np.testing.assert_allclose(np.linalg.norm(raw[:, 4:8], axis=1), 1.0, atol=1e-6)


def test_time_line(sequence: Path) -> None:
    rgb = read_file_list(sequence / "rgb.txt").stamps
    depth = read_file_list(sequence / "depth.txt").stamps
    gt = read_trajectory(sequence / "groundtruth.txt").stamps
    # colour at 30 Hz with jitter
    assert np.allclose(np.diff(rgb), 1 / 30, atol=0.004)
    # depth a few milliseconds after its colour frame, associating one to one
    offset = depth - rgb
    assert np.all((offset > 0.002) & (offset < 0.015))
    i, j = associate(rgb, depth)
    assert list(i) == list(range(12)) and list(j) == list(range(12))
    # ground truth at 100 Hz, covering the images, never on an image stamp
    assert np.allclose(np.diff(gt), 0.01, atol=1e-6)
    assert gt[0] < rgb[0] and gt[-1] > rgb[-1]
    nearest = np.min(np.abs(gt[None, :] - rgb[:, None]), axis=1)
    assert nearest.min() > 0
    assert len(np.intersect1d(np.round(gt, 6), rgb)) == 0


def test_intrinsics_are_fr3_scaled(sequence: Path, synthetic_sequence) -> None:
    cam = CameraIntrinsics.from_yaml(sequence / "intrinsics.yaml")
    # the target style declares its depth noise (the SLAM back end's model); the source
    # style's depth is exact but for its 0.2 mm steps and declares none; a global shutter
    # (every preset's timing but handheld_rpy's) declares no readout, unlike TUM's fr3
    fr3 = replace(TUM_CAMERAS["fr3"].scaled(160, 120), readout=None)
    assert cam == replace(fr3, depth_noise=DEPTH_NOISE_K)
    source = synthetic_sequence(frames=2, size=(160, 120), style="source")
    assert CameraIntrinsics.from_yaml(source / "intrinsics.yaml") == fr3


@pytest.fixture(scope="module")
def voc(synthetic_voc) -> Path:
    return synthetic_voc(images=10, size=(160, 120))


def test_voc_layout_and_palette(voc: Path) -> None:
    sets = voc / "ImageSets" / "Segmentation"
    train = (sets / "train.txt").read_text().splitlines()
    val = (sets / "val.txt").read_text().splitlines()
    assert len(train) == 8 and len(val) == 2 and not set(train) & set(val)
    assert (sets / "trainval.txt").read_text().splitlines() == sorted(train + val)
    palette = voc_palette().reshape(-1)
    seen: set[int] = set()
    for name in train + val:
        jpg = Image.open(voc / "JPEGImages" / f"{name}.jpg")
        assert jpg.format == "JPEG" and jpg.mode == "RGB" and jpg.size == (160, 120)
        png = Image.open(voc / "SegmentationClass" / f"{name}.png")
        assert png.mode == "P" and png.size == (160, 120)
        np.testing.assert_array_equal(np.array(png.getpalette()[:768]), palette)
        idx = np.asarray(png)
        values = set(np.unique(idx).tolist())
        assert values <= {0, 9, 15, 20, 255}
        # every image shows a person, chair or monitor, outlined by the void band
        assert values & {9, 15, 20} and 255 in values
        seen |= values
    assert seen == {0, 9, 15, 20, 255}


def test_voc_void_band_width(voc: Path) -> None:
    name = (voc / "ImageSets" / "Segmentation" / "val.txt").read_text().split()[0]
    idx = np.asarray(Image.open(voc / "SegmentationClass" / f"{name}.png"))
    void = idx == 255
    # the band separates classes: no object pixel touches a different class directly
    for a, b in ((idx[:, 1:], idx[:, :-1]), (idx[1:], idx[:-1])):
        touching = (a != b) & (a != 255) & (b != 255)
        assert not touching.any()
    # its width is about void_width() pixels: thinner than 3x, eroding by the width removes most
    w = void_width((160, 120))
    assert w == 2
    thick = cv2.erode(void.astype(np.uint8), np.ones((w + 2, w + 2), np.uint8))
    assert thick.sum() < 0.05 * void.sum()
    assert void.mean() < 0.15


def test_void_width_scales_like_voc() -> None:
    assert void_width((500, 375)) == 5
    assert void_width((320, 240)) == 3
    assert void_width((1000, 750)) == 10
    assert void_width((64, 48)) == 1
    assert math.isclose(void_width((250, 100)), 2.5, abs_tol=0.5)


def test_ground_truth_reads_with_evo(sequence: Path) -> None:
    """evo (the TUM tools' successor, a dev dependency) reads the ground truth as we wrote it."""
    file_interface = pytest.importorskip("evo.tools.file_interface")
    traj = file_interface.read_tum_trajectory_file(str(sequence / "groundtruth.txt"))
    ours = read_trajectory(sequence / "groundtruth.txt")
    np.testing.assert_allclose(traj.timestamps, ours.stamps)
    np.testing.assert_allclose(traj.positions_xyz, ours.positions)
    # evo keeps quaternions as w x y z, TUM files (and ours) as x y z w
    np.testing.assert_allclose(traj.orientations_quat_wxyz[:, [1, 2, 3, 0]], ours.quaternions)

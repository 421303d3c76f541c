"""``uss-export`` on bad input: exit code 1, one line on stderr naming the key or file, and
nothing written (an earlier export stays byte for byte); an FP32 / INT8 pair is only ever
replaced together, by a pair from one checkpoint."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import onnx
import pytest
import torch
import yaml
from shared_helpers import NET_YAML, fake_run, segmenter_metadata, tiny_net

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.onnx_contract import SegmenterMetadata
from uss_slam.core.schema import MAX_THREADS
from uss_slam.export import onnx as export_onnx
from uss_slam.export import verify as export_verify
from uss_slam.export.quantize import CalibrationSet

Runner = Callable[..., tuple[int, str, str]]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two uss-train run folders of the same run name with different weights."""
    root = tmp_path_factory.mktemp("runs")
    return {
        "a": fake_run(root / "a", tiny_net(seed=1)),
        "b": fake_run(root / "b", tiny_net(seed=2)),
    }


@pytest.fixture(scope="module")
def calibration(synthetic_sequence: Callable[..., Path]) -> Path:
    return synthetic_sequence(frames=6, size=(160, 120), seed=2)


@pytest.fixture(scope="module")
def pair_a(
    runs: dict[str, Path], calibration: Path, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """A folder with ``fake.onnx``, ``fake.int8.onnx`` and ``fake.verify.json`` of run a."""
    folder = tmp_path_factory.mktemp("pair") / "exports"
    export_onnx.export_checkpoint(
        runs["a"],
        folder / "fake.onnx",
        calibration=CalibrationSet.read(calibration, frames=2),
        threads=1,
    )
    return folder


def _metadata() -> SegmenterMetadata:
    return segmenter_metadata(CLASS_NAMES, experiment="unit")


def _files(folder: Path) -> dict[str, bytes]:
    """Every file in ``folder`` (hidden temporary files included) -> its bytes."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())} if folder.exists() else {}


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _checkpoint_of(model: Path) -> str:
    props = {p.key: p.value for p in onnx.load(str(model)).metadata_props}
    return SegmenterMetadata.from_props(props, model).checkpoint_sha256


def _assert_one_line(code: int, err: str, expected: str) -> None:
    assert code == 1
    assert err.splitlines() == [f"uss-export: error: {expected}"]


# ---------------------------------------------------------------------------- INT8 calibration


def _bad_calibration(kind: str, root: Path) -> tuple[list[str], str]:
    """Overrides and the expected error of one kind of bad calibration folder."""
    if kind == "unset":  # (int8=true is the caller's: a key given twice is refused)
        return [], ("int8=true needs calibration.root=<TUM RGB-D folder of target frames>")
    if kind == "missing":
        return [f"calibration.root={root}"], (
            f"calibration.root={root}: does not exist; expected a TUM RGB-D folder with rgb.txt"
        )
    root.mkdir()
    if kind == "empty":
        return [f"calibration.root={root}"], (
            f"calibration.root={root}: rgb.txt: calibration.root must be a TUM RGB-D folder "
            "with rgb.txt"
        )
    if kind == "no_frames":
        (root / "rgb.txt").write_text("# timestamp filename\n")
        return [f"calibration.root={root}"], (
            f"calibration.root={root}: rgb.txt: needs at least 2 frames, lists 0"
        )
    assert kind == "broken_image"
    (root / "rgb").mkdir()
    (root / "rgb" / "1.png").write_bytes(b"not a png")
    (root / "rgb" / "2.png").write_bytes(b"not a png")
    (root / "rgb.txt").write_text("1.0 rgb/1.png\n2.0 rgb/2.png\n")
    return (
        [f"calibration.root={root}"],
        f"calibration.root={root}: rgb/1.png: not a readable image; expected a colour image (PNG or JPEG)",
    )


@pytest.mark.parametrize("kind", ["unset", "missing", "empty", "no_frames", "broken_image"])
def test_bad_calibration_fails_before_anything_is_written(
    kind: str, runs: dict[str, Path], pair_a: Path, uss_export: Runner, tmp_path: Path
) -> None:
    overrides, expected = _bad_calibration(kind, tmp_path / "calibration")
    # No earlier export: the output folder is not even created.
    code, _, err = uss_export(f"ckpt_path={runs['b']}", "int8=true", *overrides, "out_dir=fresh")
    _assert_one_line(code, err, expected)
    assert not (tmp_path / "fresh").exists()
    # An earlier pair (of run a) stays as it was.
    shutil.copytree(pair_a, tmp_path / "exports")
    before = _files(tmp_path / "exports")
    code, _, err = uss_export(f"ckpt_path={runs['b']}", "int8=true", *overrides)
    _assert_one_line(code, err, expected)
    assert _files(tmp_path / "exports") == before


def test_int8_needs_opset_13(runs: dict[str, Path], calibration: Path, uss_export: Runner) -> None:
    code, _, err = uss_export(
        f"ckpt_path={runs['a']}", "opset=11", "int8=true", f"calibration.root={calibration}"
    )
    _assert_one_line(
        code, err, "opset 11 is too old for int8=true: per-channel INT8 weights need opset >= 13"
    )


@pytest.mark.slow  # five exports of the tiny model, three of them with INT8: ~20 s
def test_fp32_and_int8_are_replaced_together(
    runs: dict[str, Path],
    calibration: Path,
    pair_a: Path,
    uss_export: Runner,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    exports = tmp_path / "exports"
    shutil.copytree(pair_a, exports)
    pair = _files(exports)
    assert sorted(pair) == ["fake.int8.onnx", "fake.onnx", "fake.verify.json"]
    b = [f"ckpt_path={runs['b']}", "num_threads=1"]
    int8 = ["int8=true", f"calibration.root={calibration}", "calibration.frames=2"]

    # The quantiser fails after the FP32 model of b verified: nothing of b is renamed into place.
    def broken(*args: object, **kwargs: object) -> dict[str, object]:
        raise UssSlamError("quantiser refused the model")

    with monkeypatch.context() as patch:
        patch.setattr(export_onnx, "write_int8", broken)
        code, _, err = uss_export(*b, *int8)
    _assert_one_line(code, err, "quantiser refused the model")
    assert _files(exports) == pair

    # b fails verification: the pair of a stays, the failure report is written next to it.
    with monkeypatch.context() as patch:
        patch.setattr(export_verify, "MIN_LABEL_AGREEMENT", 1.5)
        code, _, err = uss_export(*b, *int8)
    assert code == 1 and len(err.splitlines()) == 1
    assert err.startswith("uss-export: error: exports/fake.onnx: exported model failed")
    after = _files(exports)
    assert after.pop("fake.verify.failed.json")
    assert after == pair

    # b without INT8: the INT8 model of a goes (it would not match), the failure report too.
    code, out, err = uss_export(*b)
    assert (code, err) == (0, "")
    assert "wrote exports/fake.onnx" in out
    assert sorted(_files(exports)) == ["fake.onnx", "fake.verify.json"]
    assert _checkpoint_of(exports / "fake.onnx") == _sha(runs["b"])
    assert "int8" not in json.loads((exports / "fake.verify.json").read_text())

    # b with INT8: both models come from b.
    code, out, err = uss_export(*b, *int8)
    assert (code, err) == (0, "")
    assert "wrote exports/fake.int8.onnx" in out
    assert sorted(_files(exports)) == ["fake.int8.onnx", "fake.onnx", "fake.verify.json"]
    for model in ("fake.onnx", "fake.int8.onnx"):
        assert _checkpoint_of(exports / model) == _sha(runs["b"])
    report = json.loads((exports / "fake.verify.json").read_text())
    assert report["checkpoint_sha256"] == _sha(runs["b"])
    assert report["int8"]["model"] == "fake.int8.onnx"
    assert report["int8"]["calibration_root"] == str(calibration)


# ---------------------------------------------------------------------------- options


def test_opset_range_of_this_install(tmp_path: Path) -> None:
    supported = export_onnx.supported_opsets()
    assert supported.start == export_onnx.MIN_OPSET == 11
    assert export_onnx.DEFAULT_OPSET in supported
    # The ends of the range found with the probe export the real graph, and it verifies.
    net = tiny_net(seed=4)
    for opset in (supported.start, supported.stop - 1):
        out = tmp_path / f"m{opset}.onnx"
        result = export_onnx.export_segmenter(net, out, _metadata(), opset=opset)
        assert result.verify["ok"] is True and result.verify["opset"] == opset
        assert {o.domain: o.version for o in onnx.load(str(out)).opset_import}[""] == opset


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("opset=abc", "opset: expected an integer, got 'abc'"),
        ("opset=17.5", "opset: expected an integer, got 17.5"),
        ("opset=true", "opset: expected an integer, got True"),
        ("opset=10", "opset 10 is not supported: "),
        ("opset=99", "opset 99 is not supported: "),
        ("trace_size=[1]", "trace_size must be [H, W], two positive integers; got [1]"),
        ("trace_size=abc", "trace_size must be [H, W], two positive integers; got 'abc'"),
        ("verify_size=[0,5]", "verify_size must be [H, W], two positive integers; got [0, 5]"),
        ("verify_size=[97,129]", "verify_size must differ from trace_size ((97, 129))"),
        ("head=side", "head: expected one of 'main', 'aux', got 'side'"),
        (
            "num_threads=0",
            f"num_threads: expected an integer >= 1 and <= {MAX_THREADS} or null, got 0",
        ),
        ("int8=maybe", "int8: expected true or false, got 'maybe'"),
        ("max_logit_diff=abc", "max_logit_diff: expected a number > 0 or null, got 'abc'"),
        ("dynamic_classes=person", "dynamic_classes: expected a list of strings, got 'person'"),
        ("out=model.txt", "out must end in .onnx, got model.txt"),
    ],
)
def test_bad_option_is_one_line(
    override: str, expected: str, runs: dict[str, Path], uss_export: Runner, tmp_path: Path
) -> None:
    code, _, err = uss_export(f"ckpt_path={runs['a']}", override)
    assert code == 1
    (line,) = err.splitlines()
    assert line.startswith(f"uss-export: error: {expected}")
    if "is not supported" in expected:
        supported = export_onnx.supported_opsets()
        assert line.endswith(f"at opset {supported.start}..{supported.stop - 1}")
    assert not (tmp_path / "exports").exists()


def test_calibration_frames_must_be_positive(
    runs: dict[str, Path], calibration: Path, uss_export: Runner, tmp_path: Path
) -> None:
    code, _, err = uss_export(
        f"ckpt_path={runs['a']}",
        "int8=true",
        f"calibration.root={calibration}",
        "calibration.frames=0",
    )
    _assert_one_line(code, err, "calibration.frames: expected an integer >= 1, got 0")
    assert not (tmp_path / "exports").exists()


def test_missing_ckpt_path(uss_export: Runner) -> None:
    code, _, err = uss_export()
    _assert_one_line(code, err, "ckpt_path=PATH is required (a uss-train .ckpt)")


def test_the_experiment_name_key(runs: dict[str, Path], uss_export: Runner, tmp_path: Path) -> None:
    """``experiment=`` would choose a uss-train preset (Hydra's config group of that name): one
    line naming ``experiment_name``; ``experiment_name=`` sets what the model stores."""
    for given in ("experiment=ci", "+experiment=ci"):
        code, _, err = uss_export(f"ckpt_path={runs['a']}", given, "out_dir=x")
        expected = f"{given}: the experiment name stored in the model is experiment_name=ci"
        _assert_one_line(code, err, f"{expected} (experiment= selects a uss-train preset)")
        assert not (tmp_path / "x").exists()
    code, _, err = uss_export(f"ckpt_path={runs['a']}", "experiment_name=mine", "out_dir=x")
    assert code == 0, err
    props = onnx.load(str(tmp_path / "x" / "fake.onnx")).metadata_props
    assert SegmenterMetadata.from_props({p.key: p.value for p in props}).experiment == "mine"


# ---------------------------------------------------------------------------- output folder


def test_output_folder_that_cannot_be_written(
    runs: dict[str, Path], uss_export: Runner, tmp_path: Path
) -> None:
    blocker = tmp_path / "blocker"
    blocker.write_text("a file where the folder should be\n")
    code, _, err = uss_export(f"ckpt_path={runs['a']}", f"out_dir={blocker}")
    _assert_one_line(code, err, f"out_dir={blocker}: is a file; expected a folder")
    code, _, err = uss_export(f"ckpt_path={runs['a']}", f"out_dir={blocker / 'sub'}")
    _assert_one_line(
        code,
        err,
        f"out_dir={blocker / 'sub'}: cannot create the output folder ({blocker} is a file); "
        "expected a folder to write into",
    )
    (tmp_path / "taken.onnx").mkdir()
    code, _, err = uss_export(f"ckpt_path={runs['a']}", "out=taken.onnx")
    _assert_one_line(code, err, "out=taken.onnx: is a folder; expected a file")
    assert blocker.read_text() == "a file where the folder should be\n"
    assert not any((tmp_path / "taken.onnx").iterdir())


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder(runs: dict[str, Path], uss_export: Runner, tmp_path: Path) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        code, _, err = uss_export(f"ckpt_path={runs['a']}", f"out_dir={locked}")
    finally:
        locked.chmod(0o755)
    _assert_one_line(
        code,
        err,
        f"out_dir={locked}: cannot write to {locked} (Permission denied); expected a folder to "
        "write into",
    )
    assert not any(locked.iterdir())


# ---------------------------------------------------------------------------- checkpoints


def _bad_checkpoint(kind: str, folder: Path, good: Path) -> tuple[Path, list[str], str]:
    """A bad checkpoint in a run folder (so the run config is found), extra overrides, and the
    expected error after ``<ckpt>: ``."""
    run = folder / "run"
    shutil.copytree(good.parent.parent, run)
    ckpt = run / "checkpoints" / "last.ckpt"
    blob = torch.load(ckpt, weights_only=True)
    unreadable = "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt ("
    if kind == "missing":
        ckpt.unlink()
        return ckpt, [], "does not exist; expected a uss-train checkpoint (.ckpt)"
    if kind == "empty":
        ckpt.write_bytes(b"")
        return ckpt, [], "empty file (expected a uss-train .ckpt)"
    if kind == "truncated":
        data = ckpt.read_bytes()
        ckpt.write_bytes(data[: len(data) // 3])
        return ckpt, [], unreadable + "RuntimeError: "
    if kind == "random":
        ckpt.write_bytes(bytes(range(256)) * 64)
        return ckpt, [], unreadable
    if kind == "plain_state_dict":
        torch.save(blob["state_dict"], ckpt)
        return ckpt, [], "not a Lightning checkpoint: no 'state_dict' (a plain state dict?)"
    if kind == "no_hyper_parameters":
        torch.save({"state_dict": blob["state_dict"]}, ckpt)
        return ckpt, [], "not a uss-train checkpoint: no 'hyper_parameters' (class names, backbone)"
    assert kind == "class_count"
    three = yaml.safe_load(NET_YAML.read_text()) | {"num_classes": 3}
    net_yaml = folder / "three.yaml"
    net_yaml.write_text(yaml.safe_dump(three))
    return (
        ckpt,
        [f"net_config={net_yaml}"],
        (
            "checkpoint has 4 classes (background, person, chair, monitor), the net config builds 3 "
            "(num_classes)"
        ),
    )


@pytest.mark.parametrize(
    "kind",
    [
        "missing",
        "empty",
        "truncated",
        "random",
        "plain_state_dict",
        "no_hyper_parameters",
        "class_count",
    ],
)
def test_bad_checkpoint_is_one_line(
    kind: str, runs: dict[str, Path], uss_export: Runner, tmp_path: Path
) -> None:
    ckpt, overrides, expected = _bad_checkpoint(kind, tmp_path, runs["a"])
    code, _, err = uss_export(f"ckpt_path={ckpt}", *overrides)
    assert code == 1
    (line,) = err.splitlines()
    named = f"ckpt_path={ckpt}"  # the path layer's form, also for the reader's problems
    assert line.startswith(f"uss-export: error: {named}: {expected}")
    assert not (tmp_path / "exports").exists()


# ---------------------------------------------------------------------------- real console script


@pytest.mark.slow  # three console-script runs, each importing torch: ~15 s
def test_console_script_prints_exactly_one_line(runs: dict[str, Path], tmp_path: Path) -> None:
    """Through the installed script: nothing else reaches stderr or stdout (no warnings, no
    graph dumps from torch's exporter, no traceback)."""
    script = Path(sys.executable).parent / "uss-export"
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(runs["a"].read_bytes()[:1000])
    good = f"ckpt_path={runs['a']}"
    cases = [
        ([good, "opset=24"], "uss-export: error: opset 24 is not supported: "),
        (
            [f"ckpt_path={truncated}"],
            f"uss-export: error: ckpt_path={truncated}: not a readable checkpoint",
        ),
        (
            [good, "int8=true", f"calibration.root={tmp_path / 'none'}"],
            f"uss-export: error: calibration.root={tmp_path / 'none'}: does not exist",
        ),
    ]
    for overrides, expected in cases:
        result = subprocess.run(
            [str(script), *overrides],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert result.returncode == 1, result.stderr
        assert result.stdout == ""
        (line,) = result.stderr.splitlines()
        assert line.startswith(expected)
    assert not (tmp_path / "exports").exists()

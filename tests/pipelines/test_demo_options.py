"""``uss-demo`` options that need no training: ``--train-threads`` reaches both trainings,
``--until``, and bad ``--sequence`` / ``--out`` values fail in one line before any work."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines import demo


def test_train_threads_override_only_when_given() -> None:
    plan = demo.PLANS["demo"]
    default = demo.train_overrides(plan, Path("/d"), "adapted")
    assert not any(o.startswith("num_threads=") for o in default)
    one = demo.train_overrides(plan, Path("/d"), "source_only", threads=1)
    assert one[: len(default)] == [
        "experiment=demo",
        "model/method=source_only",
        "paths.data_dir=/d",
        "run_name=demo_source_only",
    ]
    assert default[1] == "model/method=adaptsegnet"
    assert one[-1] == "num_threads=1"


def test_train_threads_option() -> None:
    parser = demo.build_parser()
    assert parser.parse_args([]).train_threads is None
    assert parser.parse_args(["--train-threads", "1"]).train_threads == 1
    with pytest.raises(UssSlamError, match="--train-threads must be >= 1, got 0"):
        demo.run_demo(Path("/nonexistent"), train_threads=0)


def test_until_option_and_step_counts() -> None:
    parser = demo.build_parser()
    assert parser.parse_args([]).until == "report"
    assert parser.parse_args(["--until", "data"]).until == "data"
    assert demo._steps("report") == 12 and demo._steps("data") == 1 and demo._steps("train") == 3
    with pytest.raises(UssSlamError, match="--until deploy: not a stage"):
        demo.run_demo(Path("/nonexistent"), until="deploy")


def _one_line_error(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exit_info:
        demo.main(argv)
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_sequence_folder_is_checked_before_any_work(
    tmp_path: Path, capsys, synthetic_sequence
) -> None:
    """A --sequence folder the SLAM, mIoU or report stage could not read fails at once."""
    out = tmp_path / "out"
    source = synthetic_sequence(frames=4, size=(64, 48))
    no_labels = tmp_path / "no_labels"
    shutil.copytree(source, no_labels)
    shutil.rmtree(no_labels / "labels")
    err = _one_line_error(["--out", str(out), "--experiment", "ci", "--sequence",
                           str(no_labels)], capsys)  # fmt: skip
    assert err.startswith(f"uss-demo: error: --sequence {no_labels}: ") and "labels" in err
    no_gt = tmp_path / "no_gt"
    shutil.copytree(source, no_gt)
    (no_gt / "groundtruth.txt").unlink()
    err = _one_line_error(["--out", str(out), "--sequence", str(no_gt)], capsys)
    assert err == (f"uss-demo: error: --sequence {no_gt}: {no_gt / 'groundtruth.txt'}: not "
                   "found (the demo reports ATE)")  # fmt: skip
    assert not out.exists()  # nothing was started


def test_out_that_is_a_file_is_one_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "file"
    out.write_text("x")
    err = _one_line_error(["--out", str(out)], capsys)
    assert err == f"uss-demo: error: --out {out}: exists and is not a folder"

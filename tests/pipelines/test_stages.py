"""Cached stages: complete only with the same key, the expected outputs and a stamp written
last; a stage interrupted at any point (an exception, a failed clean-up, kill -9) is redone."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from uss_slam.core.files import atomic_path, write_json_atomic
from uss_slam.pipelines.stages import STAMP, TRAINING_OUTPUTS, Progress, Stage, run_stage


def _work(folder: Path, calls: list[str], text: str = "done") -> str:
    (folder / "checkpoints").mkdir(exist_ok=True)
    (folder / "checkpoints" / "a.ckpt").write_text(text)
    calls.append(text)
    return text


def test_reused_only_with_the_same_key_and_outputs(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    calls: list[str] = []
    stage = Stage(
        folder, {"overrides": ["a=1"], "n": (1, 2)}, outputs=(Path("checkpoints/*.ckpt"),)
    )
    assert not stage.complete()
    assert run_stage(stage, lambda: _work(folder, calls)) == "done"
    assert json.loads((folder / STAMP).read_text()) == {"overrides": ["a=1"], "n": [1, 2]}
    assert stage.complete() and run_stage(stage, lambda: _work(folder, calls)) == "reused"
    again = run_stage(stage, lambda: _work(folder, calls, "again"), force=True)
    assert again == "redone (--force): again"
    other = Stage(folder, {"overrides": ["a=2"], "n": (1, 2)}, outputs=stage.outputs)
    assert not other.complete()
    (folder / "checkpoints" / "a.ckpt").unlink()  # an expected output went missing
    assert not stage.complete()
    assert calls == ["done", "again"]


def test_a_redone_stage_says_why(tmp_path: Path) -> None:
    """The status of a stage whose earlier result is not reused names what changed."""
    folder = tmp_path / "run"
    key = {"stage": "slam", "inputs": {"sequence": "s:1", "model": "m"}, "n": 3}
    stage = Stage(folder, key, outputs=(Path("metrics.json"),))
    assert stage.stale() == "not done yet"
    work = lambda: (folder / "metrics.json").write_text("{}") and "ok"  # noqa: E731
    assert run_stage(stage, work) == "ok"  # the first time: nothing to explain
    assert stage.stale() is None
    changed = Stage(folder, {**key, "inputs": {"sequence": "s:2", "model": "m"}}, stage.outputs)
    assert changed.stale() == "inputs.sequence changed"
    assert run_stage(changed, work) == "redone (inputs.sequence changed): ok"
    more = Stage(folder, {"stage": "slam", "inputs": {"sequence": "s:3"}, "x": 1}, stage.outputs)
    assert more.stale() == "inputs.model, inputs.sequence, n, x changed"
    (folder / "metrics.json").unlink()
    assert changed.stale() == f"{folder / 'metrics.json'} missing"
    assert run_stage(changed, work) == f"redone ({folder / 'metrics.json'} missing): ok"
    assert run_stage(changed, work, force=True) == "redone (--force): ok"


def test_fresh_stage_starts_from_an_empty_folder(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "old.txt").write_text("from another key")
    run_stage(Stage(folder, {"k": 1}), lambda: "ok")
    assert sorted(p.name for p in folder.iterdir()) == [STAMP]
    # fresh=False keeps what is there (a folder holding more than this stage)
    (folder / "keep.txt").write_text("x")
    run_stage(Stage(folder, {"k": 2}, fresh=False), lambda: "ok")
    assert (folder / "keep.txt").is_file()


def test_outputs_outside_the_folder(tmp_path: Path) -> None:
    model = tmp_path / "exports" / "m.onnx"
    stage = Stage(tmp_path / "exports" / ".m", {"sha": "1"}, outputs=(model,))
    run_stage(stage, lambda: model.write_text("onnx") and "exported")
    assert stage.complete()
    model.unlink()
    assert not stage.complete()


def test_a_training_whose_last_checkpoint_was_deleted_is_trained_again(tmp_path: Path) -> None:
    """A finished training stage (uss-experiments, uss-demo) is complete only while its
    ``last.ckpt`` exists: a ``best_*.ckpt`` left alone is not a result to reuse."""
    folder = tmp_path / "train"
    stage = Stage(folder, {"k": 1}, outputs=tuple(map(Path, TRAINING_OUTPUTS)))

    def train() -> str:
        (folder / "checkpoints").mkdir(parents=True, exist_ok=True)
        for name in ("best_iter0000010_miou0.5000.ckpt", "last.ckpt"):
            (folder / "checkpoints" / name).write_bytes(b"weights")
        return "trained"

    assert run_stage(stage, train) == "trained"
    assert run_stage(stage, train) == "reused"
    (folder / "checkpoints" / "last.ckpt").unlink()
    assert stage.stale() == f"{folder / 'checkpoints' / 'last.ckpt'} missing"
    assert run_stage(stage, train).endswith("trained")
    assert (folder / "checkpoints" / "last.ckpt").is_file()


def test_interrupted_work_leaves_no_stamp(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    calls: list[str] = []
    stage = Stage(folder, {"k": 1}, outputs=(Path("checkpoints/*.ckpt"),))
    run_stage(stage, lambda: _work(folder, calls))

    def broken() -> str:
        _work(folder, calls, "half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        run_stage(stage, broken, force=True)
    assert not (folder / STAMP).exists() and not stage.complete()
    assert run_stage(stage, lambda: _work(folder, calls, "redone")) == "redone"


def test_stamp_goes_before_the_folder_is_emptied(tmp_path: Path, monkeypatch) -> None:
    """A clean-up that dies half-way (kill during rmtree) must not leave a valid stamp."""
    folder = tmp_path / "run"
    calls: list[str] = []
    stage = Stage(folder, {"k": 1}, outputs=(Path("checkpoints/*.ckpt"),))
    run_stage(stage, lambda: _work(folder, calls))

    def dies(path, *args, **kwargs):
        raise KeyboardInterrupt  # stands for a kill while deleting

    monkeypatch.setattr(shutil, "rmtree", dies)
    with pytest.raises(KeyboardInterrupt):
        run_stage(stage, lambda: _work(folder, calls, "never"), force=True)
    monkeypatch.undo()
    assert (folder / "checkpoints" / "a.ckpt").is_file()  # the old content is still there
    assert not stage.complete()  # ... but not taken for a complete stage


STAGE_SCRIPT = """
import sys, time
from pathlib import Path
from uss_slam.pipelines.stages import Stage, run_stage
folder = Path(sys.argv[1])
def work():
    (folder / "part.txt").write_text("started")
    time.sleep(float(sys.argv[2]))
    (folder / "out.txt").write_text("done")
    return "done"
print(run_stage(Stage(folder, {"k": 1}, outputs=(Path("out.txt"),)), work), flush=True)
"""


@pytest.mark.slow
def test_kill_9_during_a_stage_then_rerun(tmp_path: Path) -> None:
    folder = tmp_path / "stage"
    command = [sys.executable, "-c", STAGE_SCRIPT, str(folder)]
    proc = subprocess.Popen([*command, "60"], stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (folder / "part.txt").is_file():
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert sorted(p.name for p in folder.iterdir()) == ["part.txt"]  # no stamp
    rerun = subprocess.run([*command, "0"], capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0 and rerun.stdout.strip() == "done", rerun.stderr
    assert sorted(p.name for p in folder.iterdir()) == [STAMP, "out.txt", "part.txt"]
    again = subprocess.run([*command, "0"], capture_output=True, text=True, timeout=120)
    assert again.stdout.strip() == "reused"


def test_atomic_writes(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "summary.json"
    write_json_atomic(path, {"a": 1})
    assert path.read_text() == '{\n  "a": 1\n}\n'
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert path.read_text() == '{\n  "a": 1\n}\n'  # untouched
    assert sorted(p.name for p in path.parent.iterdir()) == ["summary.json"]  # no temporary left


def test_progress_lines(capsys) -> None:
    progress = Progress(total=2)
    progress.run("a", "stage a", lambda: "ok")
    progress.run("a", "stage a again", lambda: "reused")
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "[1/2] stage a ..." and lines[1].startswith("[1/2] stage a: ok in ")
    assert lines[3].startswith("[2/2] stage a again: reused in ") and set(progress.times) == {"a"}


def test_an_interrupted_stage_with_resume_from_keeps_its_folder(tmp_path: Path) -> None:
    """A stage with ``resume_from`` (a training) interrupted half-way keeps its folder for the
    next run of the same key; another key, ``force``, or a run that failed starts afresh."""
    folder = tmp_path / "run"
    last = Path("checkpoints/last.ckpt")

    def interrupted() -> str:
        (folder / "checkpoints").mkdir()
        (folder / last).write_text("iteration 2")
        raise KeyboardInterrupt

    def seen() -> str:  # what the work finds when it starts
        return (folder / last).read_text() if (folder / last).is_file() else "nothing"

    stage = Stage(folder, {"k": 1}, outputs=(last,), resume_from=last)
    with pytest.raises(KeyboardInterrupt):
        run_stage(stage, interrupted)
    assert stage.resumable() == folder / last and not stage.complete()
    assert Stage(folder, {"k": 2}, resume_from=last).resumable() is None  # another key
    assert Stage(folder, {"k": 1}).resumable() is None  # a stage that cannot resume
    assert run_stage(stage, seen) == "iteration 2"
    assert stage.complete() and stage.resumable() is None  # finished: nothing to go on from
    assert not stage.started.exists()

    for other in ({"k": 2}, {"k": 1}):  # another key; the same key with force
        stage.stamp.unlink()
        with pytest.raises(KeyboardInterrupt):
            shutil.rmtree(folder)
            run_stage(stage, interrupted)
        again = Stage(folder, other, outputs=(last,), resume_from=last)
        assert run_stage(again, seen, force=other == {"k": 1}).endswith("nothing")

    class Failed(Exception):
        pass

    def fails() -> str:
        raise Failed

    shutil.rmtree(folder)
    with pytest.raises(KeyboardInterrupt):
        run_stage(stage, interrupted)
    with pytest.raises(Failed):
        run_stage(stage, fails)  # it went on from the file, and failed
    assert (folder / last).is_file() and stage.resumable() is None
    assert run_stage(stage, seen) == "nothing"


def test_an_unreadable_last_checkpoint_starts_the_training_again(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """``last.ckpt`` cut short (the run was killed while writing it) is no place to go on from:
    the run's checkpoints go, with a warning naming the file, and the training starts again."""
    from uss_slam.pipelines.runs import RESUME_FROM, resume_point

    assert resume_point(tmp_path) is None
    path = tmp_path / RESUME_FROM
    path.parent.mkdir()
    (path.parent / "best_iter0000002_miou0.1000.ckpt").write_bytes(b"x")
    path.write_bytes(b"PK\x03\x04 cut short")
    assert resume_point(tmp_path) is None
    assert not path.parent.exists()
    assert str(path) in caplog.text and "the training starts again" in caplog.text


def test_a_demo_training_stopped_half_way_goes_on(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    """``uss-demo``'s training stage: Ctrl-C half-way keeps the checkpoints, and the next run
    with the same settings goes on from ``last.ckpt`` and says so; ``--force`` starts over."""
    from shared_helpers import data_overrides

    from uss_slam.pipelines import demo

    common = ["experiment=ci", *data_overrides(uda_data), "logger=csv"]
    stop = ["+callbacks.stop._target_=pipeline_helpers.interrupt_at", "+callbacks.stop.iteration=2"]
    run_dir = tmp_path / "train" / "adapted"
    with pytest.raises(KeyboardInterrupt):
        demo.stage_train(run_dir, [*common, *stop], "data", force=False)
    before = (run_dir / "csv" / "metrics.csv").read_text().splitlines()
    # the same stage key as the interrupted run (the stand-in for Ctrl-C is not a setting)
    key_of = json.loads((run_dir / ".uss-started.json").read_text())
    key_of["overrides"] = common
    write_json_atomic(run_dir / ".uss-started.json", key_of)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        status = demo.stage_train(run_dir, common, "data", force=False)
    assert status.startswith("trained (went on from iteration 2), val/mIoU ")
    # no warning that the run's own folders are not empty, or that its CSV log will be deleted
    assert not [w for w in caught if "exists and is not empty" in str(w.message)]
    # the CSV log holds both parts' rows (Lightning's logger alone would drop the first part's)
    with open(run_dir / "csv" / "metrics.csv", newline="") as f:
        steps = [int(r["step"]) for r in csv.DictReader(f)]
    assert len(before) > 1 and steps == sorted(steps) and min(steps) == 0 and max(steps) >= 3
    assert not list(run_dir.glob("csv/.before-resume*"))
    assert demo.stage_train(run_dir, common, "data", force=False) == "reused"
    forced = demo.stage_train(run_dir, common, "data", force=True)
    assert forced.startswith("redone (--force): trained, val/mIoU ")

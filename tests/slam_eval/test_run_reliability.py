"""``uss-slam`` reliability: everything checked before the SLAM run (exit code 1, one stderr line
naming the key or file), the output folder never mixing two runs (atomic files, ``run.json``
written last, a failed or killed rerun), and a run in which motion filters and the object rule
really flag keypoints."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from shared_helpers import drop_in_weakref_callback, outside_staging

import uss_slam.configs
from uss_slam.core.files import file_sha256
from uss_slam.core.schema import MAX_THREADS
from uss_slam.core.tum_io import read_trajectory
from uss_slam.slam_eval.products.semantic_map import read_ply
from uss_slam.slam_eval.run import main
from uss_slam.slam_eval.scoring.run_folder import (
    MANIFEST,
    TMP_PREFIX,
    RunFolder,
    clear_outputs,
    verify_run,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _uss_slam(monkeypatch, capsys, args: list[str]) -> tuple[int, str, str]:
    """``uss-slam ARGS`` in this process: (exit code, stdout, stderr)."""
    monkeypatch.setattr(sys, "argv", ["uss-slam", *args])
    try:
        main()
        code = 0
    except SystemExit as stop:
        code = int(stop.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _snapshot(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): file_sha256(p)
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != "run.log"
    }


@pytest.fixture(scope="module")
def earlier(tmp_path_factory: pytest.TempPathFactory, synthetic_sequence) -> tuple[Path, Path]:
    """(sequence, folder of a complete earlier run: baseline over 8 frames)."""
    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path_factory.mktemp("earlier") / "run"
    done = subprocess.run(
        [sys.executable, "-m", "uss_slam.slam_eval.run", f"sequence.path={seq}",
         "sequence.max_frames=8", f"out_dir={out}", "progress=false"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert verify_run(out) == []
    return seq, out


BAD_CONFIGS = [
    (["slam.orb.n_features=abc"], "slam.orb.n_features: expected an integer >= 1 and <= 100000, got 'abc'"),
    (["slam.tracker.ratio=1.5"], "slam.tracker.ratio: expected a number > 0 and <= 1, got 1.5"),
    (["slam.map.voxel=0"], "slam.map.voxel: expected a number > 0, got 0"),
    (["eval.align=se4"], "eval.align: expected one of 'se3', 'sim3', 'none', got 'se4'"),
    (["eval.rpe_unit=minutes"], "eval.rpe_unit: expected one of 'frames', 'seconds', got 'minutes'"),
    (["eval.rpe_delta=1.5"], "eval.rpe_delta: expected a whole number of frames with rpe_unit="),
    (["eval.rpe_delta=0"], "eval.rpe_delta: expected a number > 0, got 0"),
    (["eval.max_diff=abc"], "eval.max_diff: expected a number > 0, got 'abc'"),
    (["segment=sometimes"], "segment: expected one of 'every_frame', 'keyframes', 'thread', got 'sometimes'"),
    (["filters=[semantic,teleport]"], "filters: unknown filter 'teleport'; choose from semantic"),
    (["compare=[[semantic],[flow,warp]]"], "compare[1]: unknown filter 'warp'; choose from"),
    (["compare=[]"], "compare must be a non-empty list of filter lists"),
    (["filters=[flow,flow]"], "filters: expected each filter once ('flow' is listed twice)"),
    (["slam.filter_params.flow.threshold=fast"],
     "slam.filter_params.flow.threshold: expected a number > 0, got 'fast'"),
    (["+slam.filter_params.flow.radius=3"],
     "slam.filter_params.flow.radius: unknown key; expected one of threshold, window"),
    (["slam.filter_params.semantic.dynamic_classes=[person,ghost]"],
     "unknown class 'ghost'; the project's classes are background, person, chair, monitor"),
    (["segmenter=labels", "+segmenter.model=x.onnx"],
     "segmenter.model: unknown key; expected one of latency_s, wait (the parameters of "
     "uss_slam.slam_eval.segmenters.base.LabelsSegmenter)"),
    (["segmenter=labels", "segmenter.latency_s=-1"], "segmenter.latency_s: expected a number >= 0"),
    (["segmenter=labels", "segmenter.latency_s=2.9"],
     "segmenter.latency_s=2.9 is simulated by segment=thread only; with segment=every_frame set "
     "segmenter.wait=true"),
    (["segmenter=onnx"], "segmenter.path: required by OnnxSegmenter"),
    (["segmenter=onnx", "segmenter.path=missing.onnx"], "segmenter.path=missing.onnx: does not exist"),
    (["slam.orb.bogus=1"], "slam.orb.bogus: unknown key; expected one of n_features, scale_factor"),
    (["slam.tracker.policy=harness"], "slam.tracker.policy: the harness tracking policy was "
                                      "removed (ORB-SLAM2's is the only one); commit 0fea5f3"),
    (["slam.tracker.keyframe_translation=0.2"], "slam.tracker.keyframe_translation: the harness "
                                                "policy's keyframe rule was removed; commit 0fea5f3"),
    (["segmenter=deeplab"], "segmenter: unknown option 'deeplab'; expected one of labels, none, "
                            "onnx"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("args", "message"), BAD_CONFIGS, ids=[" ".join(a) for a, _ in BAD_CONFIGS]
)
def test_bad_config_fails_before_the_run_and_keeps_the_earlier_run(
    earlier, tmp_path: Path, monkeypatch, capsys, args: list[str], message: str
) -> None:
    seq, done = earlier
    out = tmp_path / "run"
    shutil.copytree(done, out)
    before = _snapshot(out)
    code, stdout, stderr = _uss_slam(
        monkeypatch, capsys, [f"sequence.path={seq}", f"out_dir={out}", "progress=false", *args]
    )
    assert code == 1
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("uss-slam: error: ") and message in lines[0], lines[0]
    assert "Traceback" not in stderr and stdout == ""
    # Nothing of the failed run was written: the earlier run is complete and unchanged, its
    # .hydra/ included.
    assert _snapshot(out) == before and verify_run(out) == []
    overrides = yaml.safe_load((out / ".hydra" / "overrides.yaml").read_text())
    assert "sequence.max_frames=8" in overrides


def test_onnx_segmenter_threads_checked_before_loading(
    earlier, tmp_path: Path, monkeypatch, capsys
) -> None:
    seq, _ = earlier
    model = tmp_path / "model.onnx"
    model.write_bytes(b"not read: the options are checked first")
    code, _, err = _uss_slam(monkeypatch, capsys, [
        f"sequence.path={seq}", f"out_dir={tmp_path / 'out'}", "segmenter=onnx",
        f"segmenter.path={model}", "segmenter.threads=abc"])  # fmt: skip
    expected = f"segmenter.threads: expected an integer >= 1 and <= {MAX_THREADS} or null"
    assert code == 1 and err.strip().splitlines() == [f"uss-slam: error: {expected}, got 'abc'"]
    assert not (tmp_path / "out" / MANIFEST).exists()
    # more threads than the machine runs (4 per CPU): refused before any thread is started
    code, _, err = _uss_slam(monkeypatch, capsys, [
        f"sequence.path={seq}", f"out_dir={tmp_path / 'out'}", "segmenter=onnx",
        f"segmenter.path={model}", "segmenter.threads=100000"])  # fmt: skip
    assert code == 1 and err.strip().splitlines() == [f"uss-slam: error: {expected}, got 100000"]


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("fx: 0", "fx must be > 0, got 0"),
        ("fy: -535.4", "fy must be > 0, got -535.4"),
        ("fx: .nan", "fx must be a finite number, got nan"),
        ("depth_scale: 0", "depth_scale must be > 0, got 0"),
        ("depth_scale: .nan", "depth_scale must be a finite number, got nan"),
        ("cx: 320", "cx must lie inside the image (0 <= cx < width 320), got 320"),
        ("cy: -1", "cy must lie inside the image (0 <= cy < height 240), got -1"),
    ],
)
def test_bad_intrinsics_name_the_file_and_key(
    earlier, tmp_path: Path, monkeypatch, capsys, entry: str, message: str
) -> None:
    source, _ = earlier
    seq = tmp_path / "seq"
    shutil.copytree(source, seq)
    intrinsics = seq / "intrinsics.yaml"
    key = entry.split(":")[0]
    lines = [
        entry if line.split(":")[0] == key else line for line in intrinsics.read_text().splitlines()
    ]
    intrinsics.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    code, _, err = _uss_slam(monkeypatch, capsys, [f"sequence.path={seq}", f"out_dir={out}"])
    assert code == 1
    assert err.strip().splitlines() == [f"uss-slam: error: {intrinsics}: {message}"]
    assert not (out / MANIFEST).exists() and not (out / "trajectory.txt").exists()


def test_out_dir_that_cannot_be_created(earlier, tmp_path: Path, monkeypatch, capsys) -> None:
    seq, _ = earlier
    blocker = tmp_path / "file"
    blocker.write_text("a file, not a folder")
    code, _, err = _uss_slam(
        monkeypatch, capsys, [f"sequence.path={seq}", f"out_dir={blocker / 'run'}"]
    )
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(blocker / "run") in lines[0]
    assert lines[0].startswith(f"uss-slam: error: out_dir={blocker / 'run'}: cannot create the ")
    assert blocker.read_text() == "a file, not a folder"


def _missing_depth(seq: Path) -> str:
    """Found while opening the sequence: a depth frame listed but missing."""
    victim = sorted((seq / "depth").iterdir())[3]
    victim.unlink()
    return f"{seq / 'depth.txt'}:7: listed image depth/{victim.name} not found"


def _truncated_rgb(seq: Path) -> str:
    """A frame that only fails when it is decoded, half-way through the SLAM run."""
    victim = sorted((seq / "rgb").iterdir())[5]
    victim.write_bytes(b"truncated")
    return f"{victim}: not a readable image; expected a colour image (PNG or JPEG)"


@pytest.mark.parametrize("damage", [_missing_depth, _truncated_rgb], ids=["opening", "mid_run"])
def test_rerun_failing_on_the_sequence_keeps_the_earlier_run(
    earlier, tmp_path: Path, monkeypatch, capsys, damage
) -> None:
    """A sequence error (``damage`` makes it and returns its message), found while opening the
    sequence or half-way through the SLAM run."""
    source, done = earlier
    seq, out = tmp_path / "seq", tmp_path / "run"
    shutil.copytree(source, seq)
    shutil.copytree(done, out)
    before = _snapshot(out)
    message = damage(seq)
    code, _, err = _uss_slam(
        monkeypatch, capsys, [f"sequence.path={seq}", f"out_dir={out}", "progress=false"]
    )
    assert code == 1
    assert err.strip().splitlines() == [f"uss-slam: error: {message}"]
    assert _snapshot(out) == before and verify_run(out) == []


def test_successful_rerun_replaces_every_output(earlier, tmp_path: Path, monkeypatch, capsys):
    """A comparison rerun over a single run: no file of the earlier run survives."""
    seq, done = earlier
    out = tmp_path / "run"
    shutil.copytree(done, out)
    (out / "notes.txt").write_text("the user's own file")
    code, stdout, err = _uss_slam(monkeypatch, capsys, [
        f"sequence.path={seq}", f"out_dir={out}", "progress=false", "sequence.max_frames=6",
        "segmenter=labels", "compare=[[semantic]]"])  # fmt: skip
    assert code == 0, err
    assert "| metric | baseline | semantic |" in stdout
    assert verify_run(out) == []
    listed = set(json.loads((out / MANIFEST).read_text())["files"])
    present = {k for k in _snapshot(out) if k != MANIFEST}
    assert present == listed | {"notes.txt"}  # nothing unlisted beside the user's file
    assert not (out / "trajectory.txt").exists()  # the earlier single run's outputs are gone
    assert {"baseline/metrics.json", "semantic/map.ply", "comparison.md"} <= listed
    assert "compare=[[semantic]]" in yaml.safe_load((out / ".hydra/overrides.yaml").read_text())


# ------------------------------------------------------------------------ folder mechanics


def test_folder_writes_leave_nothing_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "metrics.json"
    target.write_text("old")
    folder = RunFolder(tmp_path)
    with pytest.raises(RuntimeError), folder.writing(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == [target.name]
    assert folder.files == []  # a failed write is not recorded for the manifest
    with folder.writing(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(TMP_PREFIX)
        tmp.write_text("new")
    assert target.read_text() == "new" and len(list(tmp_path.iterdir())) == 1
    assert folder.files == ["metrics.json"]


def test_verify_run_detects_changes_and_leftovers(tmp_path: Path) -> None:
    folder = RunFolder.start(tmp_path / "run")
    folder.write_text("metrics.json", "{}\n")
    folder.write_text("sub/trajectory.txt", "# t\n")
    assert verify_run(folder.root) == [f"{folder.root / MANIFEST}: missing (the run did not "
                                       "finish, or was killed)"]  # fmt: skip
    folder.commit(runs=["x"])
    assert verify_run(folder.root) == []
    (folder.root / "metrics.json").write_text("{ }\n")
    (folder.root / "report.md").write_text("stale")
    (folder.root / f"{TMP_PREFIX}map.ply.x.tmp").write_bytes(b"")
    problems = verify_run(folder.root)
    assert any("metrics.json: changed since the run" in p for p in problems)
    assert any("report.md: not listed in run.json" in p for p in problems)
    assert any("temporary file of an interrupted write" in p for p in problems)
    (folder.root / "sub/trajectory.txt").unlink()
    assert any("sub/trajectory.txt: listed in run.json but missing" in p
               for p in verify_run(folder.root))  # fmt: skip


def test_clear_outputs_removes_only_run_outputs(tmp_path: Path) -> None:
    root = tmp_path / "run"
    folder = RunFolder.start(root)
    for name in ("trajectory.txt", "metrics.json", "a+b/map.ply", "a+b/metrics.json",
                 ".hydra/config.yaml"):  # fmt: skip
        folder.write_text(name, "x")
    folder.commit()
    (root / "notes.md").write_text("mine")
    (root / "data").mkdir()
    (root / "data" / "metrics.json").write_text("mine too: not only run outputs in data/")
    (root / "data" / "frames.csv").write_text("mine")
    (root / f"{TMP_PREFIX}report.md.1.tmp").write_text("left by a kill")
    clear_outputs(root)
    left = sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))
    assert left == ["data", "data/frames.csv", "data/metrics.json", "notes.md"]


# ------------------------------------------------------------------------------ kill -9


def _check_files_whole(out: Path) -> None:
    """Every output present under its own name is complete (atomic writes)."""
    for path in out.rglob("*"):
        if path.name == "metrics.json" or path.name == "comparison.json":
            json.loads(path.read_text())
        elif path.name == "trajectory.txt":
            read_trajectory(path)
        elif path.name == "map.ply":
            read_ply(path)
        elif path.suffix == ".png":
            assert path.read_bytes().startswith(PNG_MAGIC)


@pytest.mark.slow
def test_sigkill_while_staging_keeps_the_earlier_run_and_a_rerun_recovers(
    earlier, tmp_path: Path
) -> None:
    """SIGKILL once the first run of a comparison is staged (its files written, the others
    running): the earlier run is complete and unchanged (the staging folder of the killed run
    is not part of it); a rerun removes that folder and commits a complete run."""
    seq, done = earlier
    out = tmp_path / "run"
    shutil.copytree(done, out)
    old = _snapshot(out)
    args = [sys.executable, "-m", "uss_slam.slam_eval.run", f"sequence.path={seq}",
            f"out_dir={out}", "progress=false", "sequence.max_frames=12", "segmenter=labels",
            "compare=[[semantic],[semantic,geometry]]"]  # fmt: skip
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 240
    while not any(out.glob(".uss-slam-new.*/baseline/report.md")):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.0005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    now = _snapshot(out)
    assert outside_staging(now) == old and verify_run(out) == []
    assert any(k.startswith(".uss-slam-new.") for k in now)  # the killed run's staging
    # left by the kill; the rerun takes it over
    started = json.loads((tmp_path / ".run.lock").read_text())["started"]
    rerun = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert rerun.stderr.strip().splitlines() == [
        f"uss-slam: warning: out_dir={out}: taking over the lock {tmp_path / '.run.lock'} left "
        f"by pid {proc.pid} (started {started}), which ended without releasing it"
    ]
    assert verify_run(out) == [] and not list(out.glob(".uss-slam-*"))
    assert not (tmp_path / ".run.lock").exists()
    runs = json.loads((out / MANIFEST).read_text())["runs"]
    assert runs == ["baseline", "semantic", "semantic+geometry"]


class _Killed(BaseException):
    """Stands for SIGKILL in the middle of a step: nothing after it runs."""


@pytest.mark.parametrize("moves", [0, 1, 2])
def test_a_kill_during_the_swap_is_detected_and_a_rerun_recovers(
    tmp_path: Path, monkeypatch, moves: int
) -> None:
    """Killed after ``moves`` of the new run's files were moved in (the earlier run's files
    already removed, manifest first): the folder has no ``run.json`` (verify_run says so),
    holds none of the earlier run's files, every file present is whole, and clear_outputs
    (what a rerun does) leaves no output behind."""
    import uss_slam.slam_eval.scoring.run_folder as run_folder

    root = tmp_path / "run"
    earlier_run = RunFolder.start(root)
    for name in ("trajectory.txt", "metrics.json", ".hydra/config.yaml"):
        earlier_run.write_text(name, f"old {name}\n")
    earlier_run.commit()
    new = RunFolder.start(root)
    for name in ("baseline/trajectory.txt", "baseline/metrics.json", "comparison.md",
                 ".hydra/config.yaml"):  # fmt: skip
        new.write_text(name, f"new {name}\n")
    done = []
    replace = os.replace

    def dying_replace(src, dst):
        if len(done) == moves:
            raise _Killed
        done.append(dst)
        replace(src, dst)

    monkeypatch.setattr(run_folder.os, "replace", dying_replace)
    with pytest.raises(_Killed):
        new.commit(runs=["baseline"])
    monkeypatch.undo()
    problems = verify_run(root)
    assert problems and "run.json: missing" in problems[0]
    present = {k: (root / k).read_text() for k in outside_staging(_snapshot(root))}
    assert all(text.startswith("new ") for text in present.values()), present
    assert len(present) == moves
    clear_outputs(root)
    assert outside_staging(_snapshot(root)) == {}


# ------------------------------------------------------------------------------ Ctrl-C


@pytest.mark.parametrize("mode", ["plain", "compare"])
def test_sigint_keeps_the_earlier_run_in_every_mode(earlier, tmp_path: Path, mode: str) -> None:
    """A real Ctrl-C (SIGINT) of a ``uss-slam`` process mid-run: exit code 130, the one line
    ``uss-slam: interrupted``, the earlier complete run exactly as it was. Comparison mode:
    sent once the baseline run's files are written (staged), while the next filter set runs."""
    seq, done = earlier
    out = tmp_path / "run"
    shutil.copytree(done, out)
    before = _snapshot(out)
    args = [sys.executable, "-m", "uss_slam.slam_eval.run", f"sequence.path={seq}",
            f"out_dir={out}", "progress=false"]  # fmt: skip
    if mode == "compare":
        args += ["segmenter=labels", "compare=[[semantic,geometry]]"]
        ready = lambda: any(out.glob(".uss-slam-new.*/baseline/report.md"))  # noqa: E731
    else:
        ready = (tmp_path / ".run.lock").is_file
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not ready():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.005)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["uss-slam: interrupted"], err
    assert _snapshot(out) == before and verify_run(out) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no staging, no lock left
    assert not list(out.glob(".uss-slam-*"))


def test_ctrl_c_while_a_finished_run_moves_in_waits_for_it(tmp_path: Path, monkeypatch) -> None:
    """SIGINT while the new run's files are moved into place: the move finishes (the folder
    holds the complete new run, never half of each), then KeyboardInterrupt."""
    import uss_slam.slam_eval.scoring.run_folder as run_folder

    root = tmp_path / "run"
    old = RunFolder.start(root)
    old.write_text("metrics.json", "old\n")
    old.write_text("a/metrics.json", "old\n")
    old.commit()
    new = RunFolder.start(root)
    for name in ("metrics.json", "b/trajectory.txt", "b/metrics.json"):
        new.write_text(name, "new\n")
    moves = []
    replace = os.replace

    def interrupted_replace(src, dst):
        if not moves:
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C on the first move
        moves.append(dst)
        replace(src, dst)

    monkeypatch.setattr(run_folder.os, "replace", interrupted_replace)
    with pytest.raises(KeyboardInterrupt):
        new.commit(runs=["b"])
    monkeypatch.undo()
    assert verify_run(root) == []
    assert sorted(json.loads((root / MANIFEST).read_text())["files"]) == [
        "b/metrics.json", "b/trajectory.txt", "metrics.json"
    ]  # fmt: skip
    assert not (root / "a").exists() and not list(root.glob(".uss-slam-new.*"))
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# --------------------------------------------------------------------- filters at work


def test_motion_filter_and_object_rule_flag_keypoints(synthetic_sequence, tmp_path: Path,
                                                      monkeypatch, capsys) -> None:  # fmt: skip
    """People walk through the synthetic scene: the geometry check flags keypoints on them and
    the object rule then takes the whole person (counted in metrics.json and the report)."""
    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path / "run"
    code, _, err = _uss_slam(monkeypatch, capsys, [
        f"sequence.path={seq}", f"out_dir={out}", "progress=false", "segmenter=labels",
        "filters=[geometry,object]"])  # fmt: skip
    assert code == 0, err
    metrics = json.loads((out / "metrics.json").read_text())
    kp = metrics["keypoints"]
    assert kp["flagged"]["geometry"] > 0 and kp["dropped"]["geometry"] > 0
    assert kp["flagged"]["object"] > 0 and kp["dropped"]["object"] > 0
    assert kp["extracted"] - kp["kept"] == kp["dropped"]["geometry"] + kp["dropped"]["object"]
    assert metrics["frames_tracked"] == metrics["frames"] == 30
    report = (out / "report.md").read_text()
    assert f"| geometry | {kp['flagged']['geometry']} | {kp['dropped']['geometry']} |" in report
    assert f"| object | {kp['flagged']['object']} | {kp['dropped']['object']} |" in report
    assert verify_run(out) == []


def test_relative_out_dir(earlier, tmp_path: Path, monkeypatch) -> None:
    """``run(cfg)`` without Hydra's job folder and with ``out_dir`` relative to the working
    directory (as ``uss-demo`` calls it): the manifest lists the files inside the folder, not a
    doubled path."""
    from hydra import compose, initialize_config_dir

    from uss_slam.slam_eval.run import run

    seq, _ = earlier
    monkeypatch.chdir(tmp_path)
    config_dir = Path(uss_slam.configs.__file__).parent
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
        cfg = compose(
            "slam_eval",
            overrides=[f"sequence.path={seq}", "sequence.max_frames=8", "out_dir=runs/rel",
                       "progress=false"],
        )  # fmt: skip
    run(cfg)
    manifest = json.loads((tmp_path / "runs/rel/run.json").read_text())
    assert {"trajectory.txt", "metrics.json", "report.md", "ate.png"} <= set(manifest["files"])
    assert verify_run(tmp_path / "runs/rel") == []


def test_a_ctrl_c_python_dropped_stops_the_commit_and_keeps_the_earlier_run(tmp_path: Path):
    """SIGINT that lands in a weakref callback (an import's module lock) is dropped by Python:
    the run must still not replace the earlier one, and nothing staged is left."""
    from uss_slam.core.cli import interrupts_kept

    root = tmp_path / "run"
    old = RunFolder.start(root)
    old.write_text("metrics.json", "old\n")
    old.commit()
    before = _snapshot(root)

    new = RunFolder.start(root)
    new.write_text("metrics.json", "new\n")
    with interrupts_kept():
        drop_in_weakref_callback(KeyboardInterrupt())
        with pytest.raises(KeyboardInterrupt):
            new.commit()
    new.discard()
    assert _snapshot(root) == before and verify_run(root) == []
    assert not list(root.glob(".uss-slam-*"))


def test_a_ctrl_c_as_the_staging_folder_is_made_leaves_no_staging_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C right after the staging folder exists (before the run holds it to discard): the
    interrupt comes once the folder is owned, which removes it (a run stopped at that moment
    left ``.uss-slam-new.*`` beside the earlier run's outputs)."""
    import tempfile

    from uss_slam.slam_eval.scoring import run_folder

    made = tempfile.mkdtemp

    def mkdtemp_then_ctrl_c(**kwargs: object) -> str:
        path = made(**kwargs)  # type: ignore[call-overload]
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # (the handler runs at the next call)
        return path

    monkeypatch.setattr(run_folder.tempfile, "mkdtemp", mkdtemp_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        RunFolder.start(tmp_path / "run")
    assert list((tmp_path / "run").iterdir()) == []

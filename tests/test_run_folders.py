"""Run folders owned by one run at a time, training included.

``uss-train``'s run folder (``hydra.run.dir``) is locked before Hydra writes its record or log
into it (:class:`uss_slam.core.run_folders.RunFolderCheck`): a second training started into a
folder a first one is using stops with exit code 2 and one line naming the folder and the pid
that holds it, and writes nothing there; the lock is held while the run works and gone after.
"""

# ruff: noqa: F811  (world: the shared fixture, imported, then a parameter of the tests)

from __future__ import annotations

from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from test_cli_matrix import (  # noqa: F401
    TRAIN,
    Holder,
    run_console_script,
    world,  # noqa: F401  (the fixture of the shared inputs)
)

from uss_slam.core.files import lock_held


def _argv(world: dict[str, Path], tmp_path: Path) -> list[str]:
    return [a.format(**world, tmp=tmp_path) for a in TRAIN.split()]


def _clear() -> None:
    HydraConfig.instance().cfg = None
    GlobalHydra.instance().clear()


def test_a_second_training_into_a_folder_in_use_stops(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    run = tmp_path / "run"
    holder = Holder(run)  # a first uss-train, working in run/
    monkeypatch.chdir(tmp_path)
    try:
        code, _, err = run_console_script("uss-train", _argv(world, tmp_path), monkeypatch, capsys)
    finally:
        holder.release()
        _clear()
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(
        f"uss-train: error: hydra.run.dir={run} is in use by pid {holder.proc.pid} (started "
    ), lines[0]
    assert not run.exists()  # no .hydra/ record, no log file of the second run


def test_a_training_holds_its_run_folder_while_it_runs(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    run = tmp_path / "run"
    seen: list[bool] = []

    def task(cfg: object) -> dict[str, float]:  # stands for the training
        seen.append(lock_held(run))
        return {}

    monkeypatch.setattr("uss_slam.train.train.train", task)
    monkeypatch.chdir(tmp_path)
    try:
        code, _, err = run_console_script("uss-train", _argv(world, tmp_path), monkeypatch, capsys)
    finally:
        _clear()
    assert code == 0, err
    assert seen == [True]
    assert not lock_held(run) and not list(tmp_path.glob(".*.lock"))


def test_a_failing_job_of_a_joblib_multirun_leaves_the_others_running(
    synthetic_sequence, tmp_path: Path
) -> None:
    """``hydra/launcher=joblib`` runs the jobs in worker processes: a job's user error ended its
    worker, joblib then stopped the other jobs (a run folder with an empty ``run.log``) and no
    list of the failed jobs came. Now as with the default launcher: the others finish, the
    failed job is listed, exit code 1, and the jobs' records are gone."""
    import subprocess
    import sys

    exe = Path(sys.executable).parent / "uss-slam"
    out = tmp_path / "sweep"
    argv = [str(exe), "-m", "hydra/launcher=joblib", f"sequence.path={synthetic_sequence()}",
            f"out_dir={out}", "progress=false", "sequence.stride=1,50"]  # fmt: skip
    run = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert run.returncode == 1, run.stderr
    lines = run.stderr.strip().splitlines()
    assert lines[-2] == "uss-slam: 1 of 2 jobs failed:", run.stderr
    assert lines[-1].startswith("  #1 sequence.stride=50: uss-slam: error: sequence.stride=50:")
    assert (out / "0" / "run.json").is_file()
    assert not (out / ".uss-jobs").exists()


CHDIR_APPS = {
    "uss-slam": ("uss_slam.slam_eval.run.run", "sequence.path={seq} out_dir={tmp}/out"),
    "uss-train": ("uss_slam.train.train.train", TRAIN),
    "uss-export": ("uss_slam.export.cli.run", "ckpt_path={ckpt} out_dir={tmp}/exports"),
    "uss-experiments": ("uss_slam.pipelines.experiments.cli.run_experiments", "out_dir={tmp}/exp"),
}


@pytest.mark.parametrize("prog", list(CHDIR_APPS))
def test_hydra_job_chdir_leaves_relative_paths_to_the_starting_folder(
    prog: str, world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``hydra.job.chdir=true``: Hydra changes into the run folder before the task, where a
    relative input path (``sequence.path=w/tgt``) was reported missing. Every app's task runs
    in the folder the script was started in, with one warning that the key changes nothing."""
    target, argv = CHDIR_APPS[prog]
    seen: list[str] = []

    def task(cfg: object) -> None:  # stands for the app's work (None: each app prints nothing)
        seen.append(str(Path.cwd()))

    monkeypatch.setattr(target, task)
    monkeypatch.chdir(tmp_path)
    args = [a.format(**world, tmp=tmp_path) for a in argv.split()] + ["hydra.job.chdir=true"]
    try:
        code, _, err = run_console_script(prog, args, monkeypatch, capsys)
    finally:
        _clear()
    assert code == 0, err
    assert seen == [str(tmp_path)]
    assert err.strip().splitlines()[0] == (
        f"{prog}: warning: hydra.job.chdir=true changes nothing: relative paths are read from "
        "the folder the script was started in, and the outputs go to the folders their keys name"
    )


def test_a_slam_run_with_hydra_job_chdir_reads_a_relative_sequence(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    (tmp_path / "seqs").mkdir()
    (tmp_path / "seqs" / "s").symlink_to(world["seq"])
    monkeypatch.chdir(tmp_path)
    args = ["hydra.job.chdir=true", "sequence.path=seqs/s", "out_dir=out", "progress=false"]
    try:
        code, _, err = run_console_script("uss-slam", args, monkeypatch, capsys)
    finally:
        _clear()
    assert code == 0, err
    assert (tmp_path / "out" / "run.json").is_file()


@pytest.mark.parametrize("prog", list(CHDIR_APPS))
def test_output_folders_may_name_hydras_runtime_cwd(
    prog: str, world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``out_dir=${hydra:runtime.cwd}/o`` (Hydra's documented way to name the starting folder)
    was refused: the run folders are checked before Hydra sets its own config, where the
    resolver found none ("HydraConfig was not set")."""
    target, argv = CHDIR_APPS[prog]
    seen: list[str] = []

    def task(cfg: object) -> None:  # stands for the app's work
        seen.append(str(Path.cwd()))

    monkeypatch.setattr(target, task)
    monkeypatch.chdir(tmp_path)
    args = [a.replace("{tmp}", "${{hydra:runtime.cwd}}").format(**world) for a in argv.split()]
    assert any("${hydra:runtime.cwd}" in a for a in args)
    try:
        code, _, err = run_console_script(prog, args, monkeypatch, capsys)
    finally:
        _clear()
    assert (code, err.strip()) == (0, ""), err
    assert seen == [str(tmp_path)]


@pytest.mark.parametrize("key", ["slam.workers", "slam.orb.n_features"])
def test_an_override_whose_interpolation_fails_writes_no_run_folder(
    key: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``slam.workers=${oops}``: the run-folder check read Hydra's record of the overrides
    item by item, which resolved the interpolation and failed there (Hydra only warns about a
    failing callback), before it noted the folder to undo: the refusal left ``out/run.log``."""
    monkeypatch.chdir(tmp_path)
    argv = [f"{key}=${{oops}}", f"out_dir={tmp_path}/out", "progress=false"]
    try:
        code, _, err = run_console_script("uss-slam", argv, monkeypatch, capsys)
    finally:
        _clear()
    assert code == 1
    assert err.strip().splitlines() == [
        f"uss-slam: error: {key}: cannot resolve ${{oops}} (Interpolation key 'oops' not found)"
    ]
    assert list(tmp_path.iterdir()) == []


EMPTY_SWEEPS = [
    ("uss-slam", "slam.workers=range(0)", ""),
    ("uss-slam", "segmenter=glob(zz*)", " (the options of segmenter: labels, none, onnx)"),
    ("uss-train", "seed=range(3,3)", ""),
    ("uss-export", "opset=range(17,13)", ""),
    ("uss-experiments", "seeds=range(0)", ""),
]


@pytest.mark.parametrize(("prog", "sweep", "options"), EMPTY_SWEEPS)
def test_a_sweep_with_no_value_is_refused_and_writes_nothing(
    prog: str, sweep: str, options: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """A multirun whose sweep has no value: Hydra launched 0 jobs, exited 0 and left a sweep
    folder holding only ``multirun.yaml``; now one line naming the override, exit code 1,
    nothing written."""
    monkeypatch.chdir(tmp_path)
    try:
        code, _, err = run_console_script(
            prog, ["-m", sweep, f"hydra.sweep.dir={tmp_path}/sweep"], monkeypatch, capsys
        )
    finally:
        _clear()
    assert code == 1, err
    assert err.strip().splitlines() == [
        f"{prog}: error: {sweep}: the sweep has no value, so a multirun would start no job; "
        f"expected at least one value{options}"
    ]
    assert list(tmp_path.iterdir()) == []

"""Every job's config is composed and checked in the plan, before any work (dry run or not), and a
failed rerun of a job leaves its earlier result byte for byte."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from hydra import compose, initialize_config_dir

from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import write_json_atomic
from uss_slam.core.schema import MAX_THREADS
from uss_slam.pipelines.experiments import cli, jobs, launch
from uss_slam.pipelines.experiments.plan import Job
from uss_slam.pipelines.experiments.tables.failures import table_failures
from uss_slam.pipelines.runs import SlamJob

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
PROG = [sys.executable, "-m", "uss_slam.pipelines.experiments.cli"]


def compose_experiments(*overrides: str):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("experiments", overrides=list(overrides))


BAD = [
    (
        'train.overrides=["model.max_iters=abc"]',
        "train.overrides: model.max_iters: expected an integer >= 1, got 'abc'",
    ),
    (
        'train.overrides=["bogus=1"]',
        "train.overrides: bogus: not a key of the training config (a new key needs +bogus=VALUE)",
    ),
    (
        'slam.overrides=["bogus=1"]',
        "slam.overrides: bogus: not a key of the uss-slam config (a new key needs +bogus=VALUE)",
    ),
    (
        'slam.overrides=["slam.orb.n_features=abc"]',
        "slam.overrides: slam.orb.n_features: expected an integer >= 1 and <= 100000, got 'abc'",
    ),
    (
        'slam.overrides=["slam.workers=0"]',
        f"slam.overrides: slam.workers: expected an integer >= 1 and <= {MAX_THREADS}, got 0",
    ),
    (
        'grid.method_overrides={adaptsegnet:["model.bogus=1"]}',
        "grid.method_overrides.adaptsegnet: model.bogus: not a key of the training config (a new "
        "key needs +model.bogus=VALUE)",
    ),
    (
        "train.num_threads=0",
        f"train.num_threads: expected an integer >= 1 and <= {MAX_THREADS} or null, got 0",
    ),
    (
        'init.overrides=["model.max_iters=abc"]',
        "init.overrides: model.max_iters: expected an integer >= 1, got 'abc'",
    ),
]


@pytest.mark.parametrize("dry", [True, False])
@pytest.mark.parametrize(("override", "line"), BAD)
def test_a_bad_job_setting_is_one_line_before_any_work(
    tmp_path: Path, override: str, line: str, dry: bool
) -> None:
    out = tmp_path / "out"
    cfg = compose_experiments(f"out_dir={out}", f"dry_run={str(dry).lower()}", override)
    with pytest.raises(UssSlamError) as info:
        cli.run_experiments(cfg)
    assert str(info.value) == line
    assert not (out / "data").exists() and not (out / "train").exists()
    assert not (out / "jobs").exists()


@pytest.mark.parametrize("dry", [True, False])
@pytest.mark.parametrize("section", ["params", "train", "slam"])
@pytest.mark.parametrize("value", ["0", "too_many", "two", "above_the_machine"])
def test_launcher_n_jobs_out_of_range_is_one_line(
    tmp_path: Path, section: str, dry: bool, value: str
) -> None:
    """0, a negative count that leaves no CPU (joblib's -1 = every CPU, -2 = all but one), more
    jobs than 4 per CPU, or a non-integer: one line before any work."""
    from uss_slam.core.ranges import MAX_THREADS, machine_threads

    cpus = machine_threads()
    given = {"too_many": str(-(cpus + 1)), "above_the_machine": str(MAX_THREADS + 1)}.get(
        value, value
    )
    out = tmp_path / "out"
    cfg = compose_experiments(
        f"out_dir={out}",
        f"dry_run={str(dry).lower()}",
        "launcher=joblib",
        f"++launcher.{section}.n_jobs={given}",
    )
    with pytest.raises(UssSlamError) as info:
        cli.run_experiments(cfg)
    shown = repr(int(given)) if value != "two" else "'two'"
    assert str(info.value) == (
        f"launcher.{section}.n_jobs: expected an integer in 1..{MAX_THREADS} (4 per CPU), or -1 "
        f"(every CPU) down to -{cpus} (one: this machine has {cpus} CPUs), got {shown}"
    )
    assert not (out / "data").exists()


def test_launcher_n_jobs_minus_one_is_joblibs_every_cpu(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    cfg = compose_experiments(
        f"out_dir={out}", "dry_run=true", "launcher=joblib", "launcher.params.n_jobs=-1"
    )
    cli.run_experiments(cfg)
    assert "hydra/launcher=joblib" in capsys.readouterr().out


def test_seeds_share_one_compose() -> None:
    """Jobs differing only in seed and run name compose once (the cache key drops them)."""
    from uss_slam.pipelines.experiments import validate

    validate._train_problem.cache_clear()
    base = ("experiment=ci", "paths.output_dir=/nonexistent")
    keys = {
        tuple(
            o
            for o in (*base, f"seed={s}", f"run_name=r{s}")
            if not o.startswith(validate.PER_JOB_TRAIN)
        )
        for s in range(5)
    }
    for key in keys:
        assert validate._train_problem(key) is None
    assert validate._train_problem.cache_info().currsize == 1


# ----------------------------------------------------------------- a failed rerun keeps the result


def _plan(tmp_path: Path, key: str) -> Path:
    spec = {"kind": "train", "key": {"k": key}, "overrides": [], "outputs": ["checkpoints/*.ckpt"]}
    plan_file = tmp_path / "jobs" / "train.json"
    write_json_atomic(
        plan_file, {"stage": "train", "out": str(tmp_path), "cells": {"train/a": spec}}
    )
    return plan_file


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_a_failed_rerun_leaves_the_earlier_result_byte_for_byte(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def trained(folder: Path, spec: Mapping[str, Any]) -> dict[str, Any]:
        (folder / "checkpoints").mkdir(parents=True)
        (folder / "checkpoints" / "last.ckpt").write_bytes(b"weights of the first run")
        return {"checkpoint": "checkpoints/last.ckpt", "val_mIoU": 0.5}

    def broken(folder: Path, spec: Mapping[str, Any]) -> dict[str, Any]:
        (folder / "checkpoints").mkdir(parents=True)
        (folder / "checkpoints" / "last.ckpt").write_bytes(b"half")
        raise FileNotFoundError("data/train/rgb: no such folder")

    folder = tmp_path / "train" / "a"
    monkeypatch.setitem(jobs.KINDS, "train", trained)
    assert jobs.run_cell(_plan(tmp_path, "first"), tmp_path, "train/a")["status"] == "ok"
    before = _snapshot(folder)

    monkeypatch.setitem(jobs.KINDS, "train", broken)
    plan_file = _plan(tmp_path, "second")  # another key: the job reruns
    assert jobs.run_cell(plan_file, tmp_path, "train/a")["status"] == "failed"
    after = _snapshot(folder)
    failure = json.loads(after.pop(jobs.FAILURE))
    assert after == before  # the earlier result, byte for byte
    assert failure["reason"] == "FileNotFoundError: data/train/rgb: no such folder"

    # the tables keep its figures and list the failure
    spec = json.loads(plan_file.read_text())["cells"]["train/a"]
    job = Job("train/a", spec, {"kind": "train", "method": "source_only"})
    exp = SimpleNamespace(out=tmp_path)
    status, reason, result = launch.status_of(exp, job, {}, {})  # type: ignore[arg-type]
    assert status == "ok" and result["val_mIoU"] == 0.5
    assert reason == launch.KEPT + failure["reason"] + " (log: logs/train/a.log)"
    rows = launch.result_rows(job, status, reason, result, [])
    data, lines = table_failures(rows)
    assert [r["id"] for r in data] == ["train/a"]
    assert any("rerun failed (earlier result kept)" in line for line in lines)

    # a successful rerun replaces it
    monkeypatch.setitem(jobs.KINDS, "train", trained)
    launch.clear_failure(folder)
    assert jobs.run_cell(plan_file, tmp_path, "train/a")["status"] == "ok"
    assert json.loads((folder / ".uss-demo.json").read_text()) == {"k": "second"}
    assert not (folder / jobs.FAILURE).exists()
    assert not folder.with_name(".a.next").exists()


def test_console_script_rejects_a_bad_override_before_any_work(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(
        [*PROG, f"out_dir={out}", 'train.overrides=["model.max_iters=abc"]'],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 1
    assert proc.stderr.strip() == (
        "uss-experiments: error: train.overrides: model.max_iters: expected an integer >= 1, got 'abc'"
    )
    assert not (out / "data").exists() and not (out / "train").exists()


def test_failed_jobs_are_one_line_on_stderr_and_exit_code_1(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The jobs without a new result (a failed rerun whose earlier result was kept included)
    are named on stderr, one line, after the run."""
    monkeypatch.setattr(
        cli, "run_experiments", lambda cfg: {"rows": [], "tables": {}, "failed": ["train/a"]}
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(
        sys, "argv", ["uss-experiments", f"out_dir={tmp_path}", f"hydra.run.dir={tmp_path}/h"]
    )
    with pytest.raises(SystemExit) as info:
        cli.main()
    assert info.value.code == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        "uss-experiments: error: 1 job without a new result: train/a (their reasons: the "
        "Failures table, runs.csv)"
    ]


def test_a_failed_slam_rerun_leaves_the_earlier_outputs_byte_for_byte(
    tmp_path: Path, synthetic_sequence: Callable[..., Path]
) -> None:
    """A real SLAM job: complete, then rerun with another key on a sequence folder that was
    removed (what composition cannot know): its earlier outputs stay, the failure beside them."""
    import shutil

    seq = synthetic_sequence(preset="static_xyz", frames=12)
    copy = tmp_path / "seq_copy"
    shutil.copytree(seq, copy)
    cell = "slam/harness/static_xyz/none"

    def plan(key: str) -> Path:
        spec = {
            "kind": "slam",
            "job": SlamJob(copy).to_json(),
            "key": {"sequence": key},
            "outputs": ["metrics.json"],
        }
        plan_file = tmp_path / "jobs" / "slam.json"
        write_json_atomic(plan_file, {"stage": "slam", "out": str(tmp_path), "cells": {cell: spec}})
        return plan_file

    assert jobs.run_cell(plan("first"), tmp_path, cell)["status"] == "ok"
    folder = tmp_path / cell
    before = _snapshot(folder)
    assert "metrics.json" in before and "trajectory.txt" in before

    shutil.rmtree(copy)
    failed = jobs.run_cell(plan("second"), tmp_path, cell)
    assert failed["status"] == "failed" and str(copy) in failed["reason"]
    after = _snapshot(folder)
    assert json.loads(after.pop(jobs.FAILURE))["reason"] == failed["reason"]
    assert after == before

"""Running a stage's pending jobs as one Hydra multirun (``python -m
uss_slam.pipelines.experiments.jobs -m ...`` through the configured launcher), watching them
finish, and reading each job's state back from its folder."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import write_json_atomic
from uss_slam.core.processes import ends_with_parent, watched_by_children
from uss_slam.pipelines.runs import RESUME_FROM

from . import tables as tbl
from .experiment import Experiment
from .jobs import FAILURE, RESULT, clear_failure, stage_of
from .overrides import hydra_value
from .plan import Job

NOT_RUN = "not run yet (its stage was not run)"
KEPT = "rerun failed, the earlier result kept: "
"""The reason of a job whose rerun (other inputs) failed: its row keeps the earlier result's
figures, and the Failures table lists it."""


def launcher_overrides(exp: Experiment, stage: str) -> list[str]:
    launcher = exp.launcher
    params = {**(launcher.get("params") or {}), **(launcher.get(stage) or {})}
    overrides = [f"hydra/launcher={launcher['name']}"]
    overrides += [f"hydra.launcher.{k}={hydra_value(v)}" for k, v in params.items()]
    return overrides


def launcher_section(stage: str) -> str:
    """The launcher section (``launcher.<section>``) of a stage's jobs: the pretrained inits'
    (stage ``init``) are trainings."""
    return "train" if stage == "init" else stage


def multirun_command(exp: Experiment, stage: str, plan: Path, ids: Sequence[str]) -> list[str]:
    return [
        sys.executable,
        "-m",
        "uss_slam.pipelines.experiments.jobs",
        "-m",
        f"plan={hydra_value(str(plan))}",
        f"out={hydra_value(str(exp.out))}",
        "cell=" + ",".join(hydra_value(i) for i in ids),
        *launcher_overrides(exp, launcher_section(stage)),
    ]


@dataclass
class Launch:
    """What a stage's multirun did."""

    pending: list[str]
    returncode: int | None = None  # None: nothing launched


def launch(exp: Experiment, stage: str, jobs: Sequence[Job], blocked: set[str]) -> Launch:
    """Write the stage's plan and run its pending jobs as one Hydra multirun."""
    plan = exp.out / "jobs" / f"{stage}.json"
    cells = {j.id: j.spec for j in jobs}
    pending = [
        j.id for j in jobs if j.id not in blocked and not stage_of(exp.out, j.spec, j.id).complete()
    ]
    write_json_atomic(
        plan, {"stage": stage, "out": str(exp.out), "pending": pending, "cells": cells}
    )
    if not pending:
        return Launch(pending)
    section = launcher_section(stage)
    bad = [k for k in exp.missing_launcher_keys if k.split(".")[1] in ("params", section)]
    if bad:
        raise UssSlamError(
            f"{bad[0]}: missing; launcher={exp.launcher['name']} needs it ({bad[0]}=VALUE)"
        )
    for job_id in pending:
        clear_failure(exp.out / job_id)
        (exp.out / "logs" / job_id).parent.mkdir(parents=True, exist_ok=True)
    command = multirun_command(exp, stage, plan, pending)
    log = exp.out / "logs" / f"{stage}.multirun.log"
    print(
        f"  {stage}: {len(pending)} job{'' if len(pending) == 1 else 's'} via "
        f"hydra/launcher={exp.launcher['name']} "
        f"(plan {plan}; Hydra's output in {log}, each job's in {exp.out / 'logs'})",
        flush=True,
    )
    code = _run_and_watch(exp, stage, command, log, pending)
    if code != 0:
        tail = log.read_text(errors="replace").splitlines()[-10:]
        print(
            f"  {stage}: the multirun exited with code {code}; jobs without a result are "
            f"marked missing. The end of {log}:",
            *(f"    {line}" for line in tail),
            sep="\n",
            flush=True,
        )
    return Launch(pending, code)


def _finished(exp: Experiment, stage: str, pending: Sequence[str]) -> tuple[int, int]:
    """``(done, failed)`` among the launched jobs, from their folders."""
    plan = json.loads((exp.out / "jobs" / f"{stage}.json").read_text(encoding="utf-8"))["cells"]
    done = failed = 0
    for job_id in pending:
        if stage_of(exp.out, plan[job_id], job_id).complete():
            done += 1
        elif (exp.out / job_id / FAILURE).is_file():
            failed += 1
    return done, failed


def _run_and_watch(
    exp: Experiment,
    stage: str,
    command: Sequence[str],
    log: Path,
    pending: Sequence[str],
    every: float = 2.0,
) -> int:
    """Run the multirun (its output into ``log``), printing how many jobs finished whenever
    that changes; returns its exit code."""
    t0 = time.perf_counter()
    with log.open("a", encoding="utf-8") as out:
        out.write(f"$ {shlex.join(command)}\n")
        out.flush()
        # the multirun ends with this process, even after a kill -9 of it (no survivor
        # writes into out_dir while a rerun does), and so do its jobs in the launcher's own
        # worker processes (they watch this process: jobs.run_cell)
        proc = subprocess.Popen(
            command,
            stdout=out,
            stderr=subprocess.STDOUT,
            preexec_fn=ends_with_parent(),
            env={**os.environ, **watched_by_children()},
        )
        try:
            return _watch(exp, stage, proc, pending, every, t0)
        finally:
            if proc.poll() is None:  # interrupted here: do not leave the jobs running unseen
                proc.terminate()
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()


def _watch(
    exp: Experiment,
    stage: str,
    proc: subprocess.Popen[bytes],
    pending: Sequence[str],
    every: float,
    t0: float,
) -> int:
    """Wait for ``proc``; print the count of finished jobs whenever it changes."""
    last = (0, 0)
    while True:
        try:
            code: int | None = proc.wait(timeout=every)
        except subprocess.TimeoutExpired:
            code = None
        counts = _finished(exp, stage, pending)
        if counts != last:
            last = counts
            print(
                f"  {stage}: {sum(counts)}/{len(pending)} jobs finished"
                + (f" ({counts[1]} failed)" if counts[1] else "")
                + f" after {time.perf_counter() - t0:.0f} s",
                flush=True,
            )
        if code is not None:
            return code


def status_of(
    exp: Experiment, job: Job, blocked: Mapping[str, str], launches: Mapping[str, Launch]
) -> tuple[str, str, dict[str, Any]]:
    """``(status, reason, result)`` of a job from its folder."""
    stage = stage_of(exp.out, job.spec, job.id)
    if stage.complete():
        result = json.loads((stage.folder / RESULT).read_text(encoding="utf-8"))
        if job.spec["kind"] == "slam":
            result["timing_ms"] = slam_timing(stage.folder / "metrics.json")
        return "ok", "", result
    failure = stage.folder / FAILURE
    if failure.is_file():
        record = json.loads(failure.read_text(encoding="utf-8"))
        reason = f"{record['reason']} (log: logs/{job.id}.log)"
        if (stage.folder / RESULT).is_file():  # the rerun failed: the earlier result stands
            result = json.loads((stage.folder / RESULT).read_text(encoding="utf-8"))
            if job.spec["kind"] == "slam":
                result["timing_ms"] = slam_timing(stage.folder / "metrics.json")
            return "ok", KEPT + reason, result
        return "failed", reason, {"seconds": record.get("seconds")}
    launched = launches.get("train" if job.spec["kind"] == "train" else "slam")
    if launched is None:
        return "missing", NOT_RUN, {}
    if job.id in blocked:
        return "blocked", blocked[job.id], {}
    if job.id in launched.pending:
        return (
            "missing",
            (
                f"no result: the job was killed or interrupted, or its launcher failed "
                f"(multirun exit code {launched.returncode}; log: logs/{job.id}.log)"
            ),
            {},
        )
    return "missing", "no result (not launched)", {}


def slam_timing(metrics: Path) -> dict[str, float]:
    """The mean wall ms per frame of a SLAM run's modules (its ``metrics.json``'s ``timing_ms``:
    ``segmentation``, ``segmentation.crf``, ``total``, ...; empty when it has none)."""
    try:
        timing = json.loads(metrics.read_text(encoding="utf-8")).get("timing_ms")
    except (OSError, json.JSONDecodeError):
        return {}
    return dict(timing) if isinstance(timing, dict) else {}


def result_rows(
    job: Job, status: str, reason: str, result: Mapping[str, Any], sequences: Sequence[str]
) -> list[dict[str, Any]]:
    """The ``runs.csv`` rows of a job (a segmentation evaluation has one per sequence + all)."""
    from uss_slam.core.classes import CLASS_NAMES

    base = {
        "id": job.id,
        "status": status,
        "reason": reason,
        "folder": job.id,
        "seconds": result.get("seconds"),
        **job.row,
    }
    kind = job.spec["kind"]
    if kind == "train":
        return [{**base, "val_mIoU": result.get("val_mIoU")}]
    if kind == "slam":
        ate = result.get("ate") or {}
        repeats = result.get("ate_rmse_repeats")
        if repeats is None:  # one run
            repeats = {"evaluated": 0 if ate.get("rmse") is None else 1,
                       "min": ate.get("rmse"), "max": ate.get("rmse")}  # fmt: skip
        return [
            {
                **base,
                **{f"ate_{k}": ate.get(k) for k in ("rmse", "mean", "median", "std")},
                "ate_runs": repeats.get("evaluated"),
                "ate_rmse_min": repeats.get("min"),
                "ate_rmse_max": repeats.get("max"),
                "tracked_fraction": result.get("tracked_fraction"),
                "fps": result.get("fps"),
                **{
                    column: (result.get("timing_ms") or {}).get(key)
                    for column, key in tbl.TIMING_COLUMNS.items()
                },
            }
        ]
    rows = []
    scores = result.get("sequences") or {}
    # the source validation split's evaluation has one row; the sequences' one each and "all"
    names = [job.row["sequence"]] if job.row.get("sequence") else [*sequences, tbl.ALL_SEQUENCES]
    for name in names:
        s = scores.get(name) or {}
        person = (s.get("person") or {}).get("frames") or {}
        iou = s.get("IoU") or {}
        rows.append(
            {
                **base,
                "sequence": name,
                "mIoU": s.get("mIoU"),
                **{f"IoU_{c}": iou.get(c) for c in CLASS_NAMES},
                **{f"person_{r}": person.get(r) for r in tbl.RATES},
            }
        )
    return rows


def describe_plan(exp: Experiment, stage: str, jobs: Sequence[Job], blocked: set[str]) -> str:
    complete = [j for j in jobs if stage_of(exp.out, j.spec, j.id).complete()]
    pending = [j for j in jobs if j not in complete and j.id not in blocked]
    lines = [
        f"{stage}: {len(jobs)} jobs, {len(complete)} complete, {len(pending)} to run"
        + (
            f", {len(blocked & {j.id for j in jobs})} blocked until their model exists"
            if blocked
            else ""
        )
    ]
    lines += [
        f"  to run: {j.id}"
        + (
            f" (goes on from its interrupted run's {RESUME_FROM})"
            if stage_of(exp.out, j.spec, j.id).resumable()
            else ""
        )
        for j in pending
    ]
    waiting: dict[str, list[str]] = {}
    for j in jobs:
        if j.id in blocked and j not in complete:
            waiting.setdefault(str(j.needs), []).append(j.id)
    lines += [f"  after exports/{m}: {', '.join(ids)}" for m, ids in waiting.items()]
    if pending:
        command = multirun_command(
            exp,
            stage,
            exp.out / "jobs" / f"{stage}.json",
            [j.id for j in pending[:2]] + (["..."] if len(pending) > 2 else []),
        )
        lines.append("  as: " + shlex.join(command))
    return "\n".join(lines)

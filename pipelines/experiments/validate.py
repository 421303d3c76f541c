"""Every job's config composed and checked while the plan is made (so in a dry run too), before
any work starts: a training's ``uss-train`` config (Hydra's compose, then the value types and
run settings ``uss-train`` checks before it builds anything) and a SLAM run's ``uss-slam`` config
(compose, then ``uss-slam``'s own checks). A bad entry of ``train.overrides``,
``grid.method_overrides.<method>`` or ``slam.overrides`` is one line naming that key and the
config key it sets.

Jobs that differ only in what the plan itself writes per job (seed, run name, the init file,
the sequence and model files) compose alike: each distinct set of the other overrides is
composed once."""

from __future__ import annotations

import functools
from pathlib import Path

from uss_slam.core.errors import UssSlamError
from uss_slam.core.paths import path_override

from .data import Data
from .experiment import Experiment
from .grid import METHODS, REFERENCE_METHODS, TrainCell
from .overrides import config_error_line
from .plan import Job, common_overrides, plan_slam, plan_train, runtime_overrides

PER_JOB_TRAIN = ("seed=", "run_name=", "model.net.weights_path=")
"""Training overrides the plan writes per job (checked where they are made: the grid's seeds,
the data stage's init files); left out of the composed set so that seeds share one compose."""

PER_JOB_SLAM = ("sequence.path=", "segmenter.path=", "system.vocabulary=")
"""SLAM overrides naming files (checked by the data and export stages): composed with a
stand-in path."""

_STAND_IN = "/dev/null"


def check_job_configs(exp: Experiment, data: Data) -> tuple[int, int]:
    """Compose and check the config of every training and SLAM job of the plan; returns the
    number of distinct configs composed ``(train, slam)``. Raises :class:`UssSlamError` with
    one line for the first bad one."""
    trainings = exp.grid.trainings
    jobs = plan_train(exp, data)
    train_keys = {_check_training(exp, data, c, j) for c, j in zip(trainings, jobs, strict=True)}
    slam_keys = {_check_slam(exp, j) for j in plan_slam(exp, data, {}) if j.spec["kind"] == "slam"}
    if exp.init.pretrains:  # the pretrainings of the warm start (init.overrides)
        from .warm_start import init_jobs, pretrain_set_stage

        train_keys |= {_check_init(exp, j) for j in init_jobs(exp, pretrain_set_stage(exp))}
    return len(train_keys), len(slam_keys)


def _output_dir(exp: Experiment) -> str:
    return path_override("paths.output_dir", exp.out / ".config-check")


def _check_training(exp: Experiment, data: Data, cell: TrainCell, job: Job) -> tuple[str, ...]:
    """Check a training's config; returns the overrides it was composed with."""
    overrides = tuple(o for o in job.spec["overrides"] if not o.startswith(PER_JOB_TRAIN))
    overrides = (*overrides, _output_dir(exp))
    problem = _train_problem(overrides)
    if problem is None:
        return overrides
    # which of the user's settings it is: the trainings' common ones, else the method's own
    base = (*common_overrides(exp, data), *runtime_overrides(exp), _output_dir(exp))
    line = _train_problem(base)
    if line is not None:
        given = exp.cfg["train"].get("overrides")
        raise UssSlamError(f"{'train.overrides' if given else 'train.experiment'}: {line}")
    if cell.settings:
        method = METHODS.get(cell.method) or REFERENCE_METHODS[cell.method]
        line = _train_problem((*base, *method, *cell.settings))
        if line is not None:
            raise UssSlamError(f"grid.method_overrides.{cell.method}: {line}")
    raise UssSlamError(f"training {job.id}: {problem}")


def _check_init(exp: Experiment, job: Job) -> tuple[str, ...]:
    """Check a pretraining's config; returns the overrides it was composed with."""
    overrides = tuple(o for o in job.spec["overrides"] if not o.startswith(PER_JOB_TRAIN))
    overrides = (*overrides, _output_dir(exp))
    problem = _train_problem(overrides)
    if problem is None:
        return overrides
    given = set(exp.init.overrides)
    if given and _train_problem(tuple(o for o in overrides if o not in given)) is None:
        raise UssSlamError(f"init.overrides: {problem}")
    raise UssSlamError(f"pretraining {job.id}: {problem}")


def _check_slam(exp: Experiment, job: Job) -> tuple[str, ...]:
    """Check a SLAM run's config; returns the overrides it was composed with."""
    from uss_slam.pipelines.runs import SlamJob

    slam = SlamJob.from_json(job.spec["job"])
    overrides = tuple(
        f"{o.split('=', 1)[0]}={_STAND_IN}" if o.startswith(PER_JOB_SLAM) else o
        for o in slam.overrides()
    )
    problem = _slam_problem(overrides)
    if problem is None:
        return overrides
    given = tuple(str(o) for o in exp.cfg["slam"].get("overrides") or [])
    line = (
        _slam_problem(tuple(SlamJob(Path(_STAND_IN), extra=given).overrides())) if given else None
    )
    if line is not None:
        raise UssSlamError(f"slam.overrides: {line}")
    orb = tuple(str(o) for o in (exp.cfg["slam"].get("orbslam3") or {}).get("overrides") or [])
    if orb and slam.orbslam3 is not None:
        raise UssSlamError(f"slam.orbslam3.overrides: {problem}")
    raise UssSlamError(f"SLAM job {job.id}: {problem}")


@functools.lru_cache(maxsize=512)
def _train_problem(overrides: tuple[str, ...]) -> str | None:
    """What is wrong with the ``train`` config composed with ``overrides`` (None: nothing)."""
    from uss_slam.pipelines.runs import compose_config
    from uss_slam.train.train import check_settings

    try:
        check_settings(compose_config("train", list(overrides)))
    except Exception as error:
        line = config_error_line(error, "training")
        if line is None:
            raise
        return line
    return None


@functools.lru_cache(maxsize=512)
def _slam_problem(overrides: tuple[str, ...]) -> str | None:
    """What is wrong with the ``slam_eval`` config composed with ``overrides`` (None:
    nothing)."""
    from uss_slam.pipelines.runs import compose_config
    from uss_slam.slam_eval.config import check, register_configs

    register_configs()
    try:
        check(compose_config("slam_eval", [*overrides, f"out_dir={_STAND_IN}", "progress=false"]))
    except Exception as error:
        line = config_error_line(error, "uss-slam")
        if line is None:
            raise
        return line
    return None

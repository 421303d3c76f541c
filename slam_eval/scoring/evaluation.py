"""Scoring a SLAM trajectory against ground truth, the same way for every system: ATE, RPE over
``rpe_delta`` and RPE per second (:func:`evaluate`, from an :class:`EvalConfig`), and the keys
they fill in ``metrics.json`` (:func:`scores_dict`). The metrics themselves are
:mod:`.metrics`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from uss_slam.core.errors import UssSlamError
from uss_slam.core.schema import SchemaError, check_fields, ranged
from uss_slam.core.tum_io import Trajectory

from . import metrics

STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max")
BANDS_WINDOW = 0.5
"""Seconds of the moving average that splits the ATE into its slow and fast parts."""


@dataclass(frozen=True)
class EvalConfig:
    """How trajectories are scored (TUM / evo conventions)."""

    max_diff: float = ranged(metrics.DEFAULT_MAX_DIFF, gt=0)
    """Largest rgb stamp <-> ground-truth stamp difference of an associated pair, seconds."""
    align: str = ranged("se3", choices=metrics.ALIGNMENTS)
    """Umeyama alignment of the estimate: ``se3`` | ``sim3`` | ``none``."""
    rpe_delta: float = ranged(1.0, gt=0)
    """RPE pair distance in ``rpe_unit`` (``metrics.json`` also has ``rpe_1s``, per second)."""
    rpe_unit: str = ranged("frames", choices=metrics.DELTA_UNITS)
    """``frames`` | ``seconds``."""

    def __post_init__(self) -> None:
        check_fields(self)
        if self.rpe_unit == "frames" and not float(self.rpe_delta).is_integer():
            raise SchemaError("rpe_delta", "a whole number of frames with rpe_unit=frames",
                              self.rpe_delta)  # fmt: skip


@dataclass
class Evaluation:
    """ATE / RPE of a run, or why they could not be computed."""

    ate: metrics.AteResult | None
    rpe: metrics.RpeResult | None
    rpe_1s: metrics.RpeResult | None
    error: str | None = None


def evaluate(
    trajectory: Trajectory, groundtruth: Trajectory | None, config: EvalConfig
) -> Evaluation:
    """Score ``trajectory`` against ``groundtruth`` (None -> nothing to score)."""
    if groundtruth is None:
        return Evaluation(None, None, None, "the sequence has no groundtruth.txt")
    if len(trajectory) < metrics.MIN_ASSOCIATED_POSES:
        return Evaluation(
            None, None, None, f"only {len(trajectory)} frames were tracked; ATE needs 3 poses"
        )
    try:
        ate = metrics.ate(groundtruth, trajectory, max_diff=config.max_diff, align=config.align)
        rpe = metrics.rpe(
            groundtruth,
            trajectory,
            delta=config.rpe_delta,
            unit=config.rpe_unit,
            max_diff=config.max_diff,
        )
    except UssSlamError as err:
        return Evaluation(None, None, None, str(err))
    try:
        rpe_1s = metrics.rpe(
            groundtruth, trajectory, delta=1.0, unit="seconds", max_diff=config.max_diff
        )
    except UssSlamError:
        rpe_1s = None  # shorter than a second, or gaps everywhere: reported as null
    return Evaluation(ate, rpe, rpe_1s)


def _rpe_dict(result: metrics.RpeResult | None, delta: float, unit: str) -> dict | None:
    if result is None:
        return None
    return {
        "trans": result.trans.as_dict(),
        "rot_deg": result.rot_deg.as_dict(),
        "delta": delta,
        "unit": unit,
    }


def scores_dict(evaluation: Evaluation, config: EvalConfig) -> dict[str, Any]:
    """The scoring keys of ``metrics.json``, in this order: ``ate`` (statistics in metres),
    ``rpe`` (over ``rpe_delta`` ``rpe_unit``), ``rpe_1s`` (per second), ``ate_bands`` (the ATE's
    slow and fast parts over ``BANDS_WINDOW`` seconds, :func:`.metrics.ate_bands`), ``ate_error``
    (why there is no score, else null) and ``evaluation`` (``max_diff`` seconds, ``align``)."""
    return {
        "ate": evaluation.ate.stats.as_dict() if evaluation.ate else None,
        "rpe": _rpe_dict(evaluation.rpe, config.rpe_delta, config.rpe_unit),
        "rpe_1s": _rpe_dict(evaluation.rpe_1s, 1.0, "seconds"),
        "ate_bands": (
            metrics.ate_bands(evaluation.ate, BANDS_WINDOW).as_dict() if evaluation.ate else None
        ),
        "ate_error": evaluation.error,
        "evaluation": {"max_diff": config.max_diff, "align": config.align},
    }

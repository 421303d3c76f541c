"""Repeated runs of one configuration: their seeded perturbations, the median run, the spread.

One harness run is deterministic, but its trajectory error moves far more than its inputs do:
1% more or fewer features, or another order of the matches handed to RANSAC, can change the
ATE RMSE by tens of percent. A figure is therefore the median of repeated runs, reported with
its minimum and maximum, as ORB-SLAM3's runs (which vary by themselves, through its threads).

``slam.repeats=N`` runs the harness ``N`` times per filter set (:func:`perturbations`):

- repeat 0 is the unperturbed run, byte for byte the run without repeats;
- repeat ``i >= 1`` draws from a generator seeded with ``(slam.repeat_seed, i)``: the ORB
  feature budget ``orb.n_features`` scaled by a factor uniform in
  ``[1 - slam.repeat_budget, 1 + slam.repeat_budget]`` (rounded), and a seed for the tracker's
  RANSAC sampling (the order of the matches handed to OpenCV's RANSAC is permuted, or USAC's
  generator seeded, :meth:`~uss_slam.slam_eval.tracking.tracker.Tracker._sampling_order`).

The same ``(repeat_seed, i)`` gives the same perturbation on every sequence and filter set, so
comparisons are paired by repeat. The outputs of the median run (by ATE RMSE; for an even count
the lower of the two middle runs, so that it is a real run) are the run's outputs; every
repeat's trajectory is kept as ``repeats/trajectory_<i>.txt``, and ``metrics.json`` gets the
keys that ORB-SLAM3's repeated runs have (:func:`repeats_metrics`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.tum_io import StrPath, write_trajectory

from .run_folder import RunFolder
from .run_result import RunResult


@dataclass(frozen=True)
class Perturbation:
    """What repeat ``index`` changes: the ORB feature budget and the RANSAC sampling seed
    (None for repeat 0, the unperturbed run)."""

    index: int
    n_features: int
    sampling_seed: int | None


def perturbations(count: int, seed: int, budget: float, n_features: int) -> list[Perturbation]:
    """The ``count`` perturbations of a repeated run (module docstring); ``budget`` is the
    relative half-width of the feature-budget jitter (0.01 = ±1%), ``n_features`` the
    configured budget."""
    if count < 1:
        raise ValueError(f"repeats must be >= 1, got {count}")
    out = [Perturbation(0, n_features, None)]
    for index in range(1, count):
        rng = np.random.default_rng([seed, index])
        factor = 1.0 + rng.uniform(-budget, budget)
        out.append(
            Perturbation(index, max(1, round(n_features * factor)), int(rng.integers(0, 2**31 - 1)))
        )
    return out


def median_index(rmses: Sequence[float | None]) -> int:
    """Index of the median run by ATE RMSE (a run without ATE counts as the worst); for an
    even count the lower of the two middle runs, so the reported median is a real run's."""
    order = sorted(range(len(rmses)), key=lambda i: (math.inf if rmses[i] is None else rmses[i], i))
    return order[(len(order) - 1) // 2]


def spread(values: Sequence[float | None]) -> dict[str, float | int | None]:
    """``{"median", "min", "max", "evaluated"}`` of the values that exist (None = a run that
    could not be evaluated); the median is the middle value (lower middle for an even count),
    as :func:`median_index`."""
    present = sorted(v for v in values if v is not None)
    return {
        "median": present[(len(present) - 1) // 2] if present else None,
        "min": present[0] if present else None,
        "max": present[-1] if present else None,
        "evaluated": len(present),
    }


def _rmse(metrics: dict[str, Any], *keys: str) -> float | None:
    node: Any = metrics
    for key in keys:
        node = node.get(key) if isinstance(node, dict) else None
    return None if node is None else float(node)


def repeats_metrics(
    runs: Sequence[dict[str, Any]],
    plan: Sequence[Perturbation],
    trajectories: Sequence[str],
    labels_reused: bool = False,
) -> dict[str, Any]:
    """The ``metrics.json`` keys of a repeated run, from each repeat's metrics (in repeat
    order) and the relative paths of their trajectories (``labels_reused``: repeats after the
    first took repeat 0's labels instead of segmenting, ``slam.reuse_labels``):

    - ``ate_rmse_repeats`` / ``rpe_trans_rmse_repeats``: ``median``, ``min``, ``max`` (metres)
      and ``evaluated`` (repeats with a value), over the repeats (the ATE median is the median
      run's, so it equals the folder's ``ate.rmse``);
    - ``median_repeat``: the index of the median run, whose outputs the folder holds;
    - ``repeats``: per repeat ``index``, ``n_features``, ``sampling_seed``, ``trajectory``,
      ``ate_rmse``, ``rpe_trans_rmse``, ``ate_error``, ``tracked_fraction``, ``keyframes``,
      ``fps``, ``labels_reused`` (this repeat did not segment: its ``fps`` is without the
      segmenter's cost);
    - ``timing_repeat``: the repeat whose timing figures (``timing_ms``, ``cpu_ms``, ``fps``,
      ``wall_time_s``, ``segmentation``) the folder reports: the median run's, or repeat 0's
      when the others reused its labels.
    """
    ate = [_rmse(m, "ate", "rmse") for m in runs]
    rpe = [_rmse(m, "rpe", "trans", "rmse") for m in runs]
    median = median_index(ate)
    # The median run's own value (None if even it was not evaluated), as for ORB-SLAM3.
    ate_spread = {**spread(ate), "median": ate[median]}
    return {
        "ate_rmse_repeats": ate_spread,
        "rpe_trans_rmse_repeats": spread(rpe),
        "median_repeat": plan[median].index,
        "timing_repeat": plan[0].index if labels_reused else plan[median].index,
        "repeats": [
            {
                "index": p.index,
                "n_features": p.n_features,
                "sampling_seed": p.sampling_seed,
                "trajectory": path,
                "ate_rmse": a,
                "rpe_trans_rmse": r,
                "ate_error": m.get("ate_error"),
                "tracked_fraction": m["tracked_fraction"],
                "keyframes": m["keyframes"],
                "fps": m["fps"],
                "labels_reused": labels_reused and i > 0,
            }
            for i, (p, path, a, r, m) in enumerate(
                zip(plan, trajectories, ate, rpe, runs, strict=True)
            )
        ],
    }


def write_repeat_trajectories(
    out_dir: StrPath, results: Sequence[RunResult], folder: RunFolder
) -> list[str]:
    """Every repeat's trajectory as ``out_dir/repeats/trajectory_<i>.txt`` (recorded in the run
    folder's manifest); returns their paths relative to ``out_dir``."""
    paths = []
    for index, result in enumerate(results):
        relative = f"repeats/trajectory_{index}.txt"
        with folder.writing(Path(out_dir) / relative) as tmp:
            write_trajectory(
                tmp,
                result.trajectory,
                comment=f"uss-slam estimate, repeat {index}, filters={result.filters}, "
                "camera-to-world",
            )
        paths.append(relative)
    return paths


def repeats_md(data: dict[str, Any]) -> list[str]:
    """The repeats section of ``report.md`` (empty for a single run)."""
    if "repeats" not in data:
        return []

    def fmt(value: float | None) -> str:
        return "—" if value is None else f"{value:.4f}"

    ate = data["ate_rmse_repeats"]
    lines = [
        "## Repeats",
        "",
        f"{len(data['repeats'])} runs (feature budget and RANSAC sampling perturbed, repeat 0 "
        f"unperturbed); ATE RMSE median {fmt(ate['median'])} m (min {fmt(ate['min'])}, max "
        f"{fmt(ate['max'])}, {ate['evaluated']} evaluated). This report and `trajectory.txt` "
        f"are those of the median run, repeat {data['median_repeat']}."
        + (
            " The time per frame is repeat 0's: the later repeats reused its labels instead of "
            "segmenting again (`slam.reuse_labels`), so their frames/s leave the segmenter out."
            if any(r.get("labels_reused") for r in data["repeats"])
            else ""
        ),
        "",
        "| repeat | features | sampling seed | ATE RMSE [m] | RPE trans RMSE [m] | tracked "
        "| keyframes | frames/s | trajectory |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in data["repeats"]:
        seed = "—" if r["sampling_seed"] is None else str(r["sampling_seed"])
        lines.append(
            f"| {r['index']} | {r['n_features']} | {seed} | {fmt(r['ate_rmse'])} | "
            f"{fmt(r['rpe_trans_rmse'])} | {100 * r['tracked_fraction']:.1f}% | "
            f"{r['keyframes']} | {r['fps']:.1f} | `{r['trajectory']}` |"
        )
    lines.append("")
    return lines


def with_timing_of(result: RunResult, timed: RunResult) -> RunResult:
    """``result`` with the timing figures of ``timed`` (the repeat that ran the segmenter, when
    the others reused its labels): wall and CPU ms per module, the run's wall time (its fps) and
    the segmenter's ms per segmented frame."""
    return replace(
        result,
        timing_ms=timed.timing_ms,
        cpu_ms=timed.cpu_ms,
        wall_time_s=timed.wall_time_s,
        segmentation_ms=timed.segmentation_ms,
    )

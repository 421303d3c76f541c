"""Report helpers: evaluation against ground truth, improvement percentages, missing data."""

from __future__ import annotations

import numpy as np
import pytest

from uss_slam.core.tum_io import Trajectory
from uss_slam.slam_eval.scoring.evaluation import EvalConfig, evaluate, scores_dict
from uss_slam.slam_eval.scoring.report import error_table_md, improvement


def _trajectory(stamps: np.ndarray, offset: float = 0.0) -> Trajectory:
    poses = np.tile(np.eye(4), (len(stamps), 1, 1))
    poses[:, 0, 3] = np.sin(stamps)
    poses[:, 1, 3] = np.cos(stamps) + offset
    poses[:, 2, 3] = 0.1 * stamps
    return Trajectory.from_matrices(stamps, poses)


def test_evaluate_scores_a_rigidly_moved_copy_as_zero() -> None:
    stamps = np.arange(0, 3, 1 / 30)
    gt = _trajectory(stamps)
    est = _trajectory(stamps + 0.001, offset=5.0)  # 1 ms later, shifted by 5 m
    scores = evaluate(est, gt, EvalConfig())
    assert scores.error is None
    assert scores.ate is not None and scores.ate.stats.pairs == len(stamps)
    assert scores.ate.stats.rmse < 2e-3  # only the 1 ms stamp offset remains
    assert scores.rpe is not None and scores.rpe_1s is not None
    assert scores.rpe.trans.pairs == len(stamps) - 1


def test_evaluate_explains_what_is_missing() -> None:
    stamps = np.arange(0, 1, 1 / 30)
    assert evaluate(_trajectory(stamps), None, EvalConfig()).error == (
        "the sequence has no groundtruth.txt"
    )
    few = evaluate(_trajectory(stamps[:2]), _trajectory(stamps), EvalConfig())
    assert few.ate is None and "only 2 frames were tracked" in few.error
    apart = evaluate(_trajectory(stamps + 100.0), _trajectory(stamps), EvalConfig())
    assert apart.ate is None and apart.error  # nothing associates: the metrics error is kept


def test_improvement_percent() -> None:
    assert improvement(0.75, 0.0139) == pytest.approx(98.1466666)
    assert improvement(0.01, 0.02) == pytest.approx(-100.0)
    assert improvement(None, 0.1) is None and improvement(0.0, 0.1) is None


def test_metrics_and_report_split_the_ate_into_slow_and_fast_parts() -> None:
    stamps = np.arange(0, 10, 1 / 30)
    gt = _trajectory(stamps)
    jitter = _trajectory(stamps)
    jitter.positions[:, 2] += 0.004 * (-1.0) ** np.arange(len(stamps))  # 4 mm per frame
    data = scores_dict(evaluate(jitter, gt, EvalConfig()), EvalConfig())
    bands = data["ate_bands"]
    assert bands["window_s"] == 0.5 and bands["rmse"] == pytest.approx(data["ate"]["rmse"])
    assert bands["fast"] > 0.0035 and bands["slow"] < 0.0005
    lines = "\n".join(error_table_md(data))
    assert f"{bands['slow']:.4f} m is slow (the error averaged over 0.5 s" in lines
    assert f"and {bands['fast']:.4f} m fast (per-frame jitter)" in lines
    missing = scores_dict(evaluate(jitter, None, EvalConfig()), EvalConfig())
    assert missing["ate_bands"] is None
    assert "slow" not in "\n".join(error_table_md(missing))

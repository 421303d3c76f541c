"""Repeated harness runs: the seeded perturbations, the median run and its spread, the outputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import compose_slam_eval

from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import TUM_CAMERAS, read_trajectory
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.scoring.repeats import (
    Perturbation,
    median_index,
    perturbations,
    repeats_metrics,
    spread,
)
from uss_slam.slam_eval.scoring.run_folder import verify_run
from uss_slam.slam_eval.tracking.tracker import Tracker, TrackerConfig


def _poses(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if not line.startswith("#")]


def test_repeat_zero_is_the_unperturbed_run_and_the_others_are_seeded() -> None:
    plan = perturbations(5, seed=3, budget=0.01, n_features=1000)
    assert plan[0] == Perturbation(0, 1000, None)
    assert [p.index for p in plan] == [0, 1, 2, 3, 4]
    for p in plan[1:]:
        assert 990 <= p.n_features <= 1010 and p.sampling_seed is not None
    assert perturbations(5, seed=3, budget=0.01, n_features=1000) == plan  # reproducible
    # The first repeats do not depend on how many follow (paired across runs of any length).
    assert perturbations(3, seed=3, budget=0.01, n_features=1000) == plan[:3]
    other = perturbations(5, seed=4, budget=0.01, n_features=1000)
    assert [p.sampling_seed for p in other[1:]] != [p.sampling_seed for p in plan[1:]]
    assert all(p.n_features == 1000 for p in perturbations(4, 3, 0.0, 1000))
    with pytest.raises(ValueError, match="repeats must be >= 1"):
        perturbations(0, 0, 0.01, 1000)


def test_median_run_and_spread() -> None:
    assert median_index([0.3, 0.1, 0.2]) == 2
    assert median_index([0.3, 0.1]) == 1  # an even count: the lower middle run
    assert median_index([None, 0.5, 0.1]) == 1  # a run without ATE counts as the worst
    assert spread([0.3, None, 0.1, 0.2]) == {"median": 0.2, "min": 0.1, "max": 0.3, "evaluated": 3}
    assert spread([None]) == {"median": None, "min": None, "max": None, "evaluated": 0}


def test_repeats_metrics_reports_the_median_run() -> None:
    plan = perturbations(3, 0, 0.01, 1000)
    runs = [
        {"ate": {"rmse": r}, "rpe": {"trans": {"rmse": r / 2}}, "tracked_fraction": 1.0,
         "keyframes": 10 + i, "fps": 20.0, "ate_error": None}
        for i, r in enumerate((0.03, 0.01, 0.02))
    ]  # fmt: skip
    paths = [f"repeats/trajectory_{i}.txt" for i in range(3)]
    data = repeats_metrics(runs, plan, paths)
    assert data["median_repeat"] == 2
    assert data["ate_rmse_repeats"] == {"median": 0.02, "min": 0.01, "max": 0.03, "evaluated": 3}
    assert data["rpe_trans_rmse_repeats"]["median"] == 0.01
    assert [r["n_features"] for r in data["repeats"]] == [p.n_features for p in plan]
    assert data["repeats"][1]["keyframes"] == 11 and data["repeats"][2]["trajectory"] == paths[2]


def test_sampling_seed_permutes_only_the_ransac_input_order() -> None:
    extractor = OrbExtractor(OrbConfig(), TUM_CAMERAS["fr3"])
    plain = Tracker(TrackerConfig(), extractor)
    assert plain.sampler.sampling_order(7) == slice(None)
    a = Tracker(TrackerConfig(), extractor, sampling_seed=5).sampler.sampling_order(50)
    b = Tracker(TrackerConfig(), extractor, sampling_seed=5).sampler.sampling_order(50)
    c = Tracker(TrackerConfig(), extractor, sampling_seed=6).sampler.sampling_order(50)
    assert np.array_equal(np.sort(a), np.arange(50)) and np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_repeated_run_writes_the_median_run_and_every_trajectory(
    synthetic_sequence, tmp_path: Path
) -> None:
    seq = synthetic_sequence(preset="static_xyz", frames=30)
    base = [f"sequence.path={seq}", "progress=false", "sequence.max_frames=20"]
    single = run(compose_slam_eval([*base, f"out_dir={tmp_path / 'one'}"]))
    assert "ate_rmse_repeats" not in single and "repeats" not in single
    data = run(compose_slam_eval([*base, f"out_dir={tmp_path / 'three'}", "slam.repeats=3"]))
    out = tmp_path / "three"
    assert verify_run(out) == []
    reps = data["repeats"]
    assert [r["index"] for r in reps] == [0, 1, 2]
    # Repeat 0 is the single run, pose lines byte for byte (the comment names the repeat).
    assert _poses(out / "repeats" / "trajectory_0.txt") == _poses(
        tmp_path / "one" / "trajectory.txt"
    )
    assert reps[0]["ate_rmse"] == single["ate"]["rmse"]
    median = reps[data["median_repeat"]]
    assert data["ate_rmse_repeats"]["median"] == median["ate_rmse"] == data["ate"]["rmse"]
    rmses = [r["ate_rmse"] for r in reps]
    assert data["ate_rmse_repeats"]["min"] == min(rmses)
    assert data["ate_rmse_repeats"]["max"] == max(rmses)
    assert _poses(out / "trajectory.txt") == _poses(out / median["trajectory"])
    for r in reps:
        assert len(read_trajectory(out / r["trajectory"])) == 20
    assert json.loads((out / "metrics.json").read_text())["median_repeat"] == data["median_repeat"]
    report = (out / "report.md").read_text()
    assert "## Repeats" in report and "| 2 |" in report
    # A rerun with one repeat leaves no trajectory of the earlier repeats behind.
    run(compose_slam_eval([*base, f"out_dir={out}"]))
    assert not (out / "repeats").exists() and verify_run(out) == []


def test_bad_repeat_settings_are_one_clear_line(synthetic_sequence, tmp_path: Path) -> None:
    seq = synthetic_sequence(preset="static_xyz", frames=30)
    base = [f"sequence.path={seq}", f"out_dir={tmp_path}", "progress=false"]
    with pytest.raises(
        UssSlamError, match=r"^slam\.repeats: expected an integer >= 1 and <= 1000, got 0$"
    ):
        run(compose_slam_eval([*base, "slam.repeats=0"]))
    with pytest.raises(
        UssSlamError, match=r"^slam\.repeat_budget: expected a number >= 0 and < 0\.5, got 0\.7$"
    ):
        run(compose_slam_eval([*base, "slam.repeat_budget=0.7"]))

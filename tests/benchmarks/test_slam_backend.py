"""benchmarks/slam_backend.py: a run's line says what local BA did, also when it never ran;
uss_slam.testing.harness_runs: a run's error splits into slow and fast parts."""

from __future__ import annotations

from pathlib import Path

import pytest

from uss_slam.testing.scripts import load_script

slam_backend = load_script(Path(__file__).resolve().parents[2] / "benchmarks" / "slam_backend.py")
_local_ba_text = slam_backend._local_ba_text


def test_local_ba_text_for_every_kind_of_run() -> None:
    assert _local_ba_text({"local_ba_ms": None, "local_ba_cpu_ms": None}) == ""  # no local BA
    # a still camera makes one keyframe: local BA is on but never runs (it crashed the line)
    never = {"local_ba_ms": 0.0, "local_ba_cpu_ms": None}
    assert _local_ba_text(never) == "  local BA never ran (one keyframe)"
    ran = {"local_ba_ms": 310.4, "local_ba_cpu_ms": 69.2}
    assert _local_ba_text(ran) == "  local BA 69 ms CPU (310 wall)"


def test_a_run_reports_its_error_split_into_slow_and_fast_parts(synthetic_sequence) -> None:
    from uss_slam.testing.harness_runs import run

    path = synthetic_sequence(preset="walking_xyz", frames=30)
    r = run(path, "tracker", ["semantic"])
    assert r["ate_rmse"] > 0 and r["ate_slow"] >= 0 and r["ate_fast"] >= 0
    # the two parts are orthogonal up to the moving average's edges
    assert r["ate_slow"] ** 2 + r["ate_fast"] ** 2 == pytest.approx(r["ate_rmse"] ** 2, rel=0.25)

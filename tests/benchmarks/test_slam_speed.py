"""benchmarks/slam_speed.py: ``MODE/N`` runs a prefetch mode with N reading threads, and the
``readers`` pair gives the worker process two threads and one, with the same trajectory."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems import harness
from uss_slam.testing.scripts import load_script

slam_speed = load_script(Path(__file__).resolve().parents[2] / "benchmarks" / "slam_speed.py")


def test_readers_pair_changes_only_the_reading_threads(synthetic_sequence, monkeypatch) -> None:
    assert slam_speed.PAIRS["readers"] == ["process:w", "process/1:w"]
    seq = TumSequence(synthetic_sequence(preset="walking_xyz", frames=30), load_labels=True)
    args = argparse.Namespace(filters=["semantic"], local_ba=False, loop_closing=False)
    built: list[int] = []
    init = harness.SlamPipeline.__init__

    def recording(self, *a, **kw):
        init(self, *a, **kw)
        built.append(self.workers)
        assert self.reader_threads is None  # the worker process's threads are slam.workers

    monkeypatch.setattr(harness.SlamPipeline, "__init__", recording)
    two, one = (slam_speed.timed_run(seq, args, mode) for mode in slam_speed.PAIRS["readers"])
    assert built == [2, 1]
    assert two["used"] == one["used"]  # the worker process (the threads where none can start)
    assert two["ate"] == one["ate"] and two["tracked"] == one["tracked"] == 1.0


def test_candidate_settings_reach_the_candidate_run_only(synthetic_sequence, monkeypatch) -> None:
    seq = TumSequence(synthetic_sequence(preset="walking_xyz", frames=30), load_labels=True)
    items = ["tracker.pose_tolerance=1e-7", "local_ba_params.first_iterations=10"]
    args = argparse.Namespace(
        filters=["semantic"], local_ba=True, loop_closing=False, candidate=items
    )
    built: list[tuple[float, int]] = []
    init = harness.SlamPipeline.__init__

    def recording(self, *a, **kw):
        init(self, *a, **kw)
        built.append((self.tracker_config.pose_tolerance, kw.get("local_ba_params")))

    monkeypatch.setattr(harness.SlamPipeline, "__init__", recording)
    for mode in ("thread", "thread+candidate"):
        slam_speed.timed_run(seq, args, mode)
    (today, none), (tolerance, ba) = built
    assert (today, none, tolerance, ba.first_iterations) == (1e-5, None, 1e-7, 10)
    for bad in ("tracker.nope=1", "slam.tracker.pose_tolerance=1e-5", "tracker.pose_tolerance=0"):
        with pytest.raises(SystemExit, match="--candidate"):
            slam_speed.candidate_settings([bad])

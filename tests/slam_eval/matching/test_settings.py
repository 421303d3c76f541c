"""The matching package's own settings hold the tracker's defaults, and the tracker hands its
configured values to them."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.matching import sampling, settings_of
from uss_slam.slam_eval.matching.projection import MatchThresholds
from uss_slam.slam_eval.matching.sampling import SamplingSettings
from uss_slam.slam_eval.tracking.tracker import Tracker, TrackerConfig


def test_the_matching_settings_are_the_trackers() -> None:
    assert settings_of(MatchThresholds, TrackerConfig()) == MatchThresholds()
    assert settings_of(SamplingSettings, TrackerConfig()) == SamplingSettings()
    ex = OrbExtractor(OrbConfig(), TUM_CAMERAS["fr3"].scaled(320, 240))
    config = TrackerConfig(max_hamming=64, ratio=0.6, sampler="prosac", refine_rounds=2)
    tracker = Tracker(config, ex)
    assert tracker.projection.config == MatchThresholds(64, 0.6, True)
    assert tracker.sampler.config == SamplingSettings("prosac", 100, 3.0, 2, True)
    assert tracker.projection.map is tracker.map


def test_the_pose_tolerance_reaches_the_refinement(monkeypatch) -> None:
    ex = OrbExtractor(OrbConfig(), TUM_CAMERAS["fr3"].scaled(320, 240))
    tracker = Tracker(TrackerConfig(pose_tolerance=1e-4), ex)
    assert SamplingSettings().pose_tolerance == TrackerConfig().pose_tolerance == 1e-5
    used: list[float] = []

    def recording(k, bf, pose_cw, *args, tolerance, **kwargs):
        used.append(tolerance)
        return pose_cw

    monkeypatch.setattr(sampling, "optimise_pose", recording)
    rng = np.random.default_rng(0)
    n = 40
    features = SimpleNamespace(
        uv=rng.uniform(50, 250, (n, 2)),
        octave=np.zeros(n, np.int32),
        depth=rng.uniform(1, 3, n).astype(np.float32),
    )
    world = np.column_stack([(features.uv - 160) / 250 * features.depth[:, None], features.depth])
    kp = np.arange(n)
    tracker.sampler.refine_pose(world, features, kp, np.eye(4))
    tracker.sampler.optimise_all(world, features, kp, np.eye(4))
    assert used and set(used) == {1e-4}

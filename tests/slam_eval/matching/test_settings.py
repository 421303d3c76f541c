"""The matching package's own settings hold the tracker's defaults, and the tracker hands its
configured values to them."""

from __future__ import annotations

from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.matching import settings_of
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


def test_the_pose_tolerance_reaches_the_refinement() -> None:
    ex = OrbExtractor(OrbConfig(), TUM_CAMERAS["fr3"].scaled(320, 240))
    tracker = Tracker(TrackerConfig(pose_tolerance=1e-5), ex)
    assert tracker.sampler.config.pose_tolerance == 1e-5
    assert SamplingSettings().pose_tolerance == TrackerConfig().pose_tolerance == 1e-7

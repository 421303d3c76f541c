"""ORB-SLAM2's RGB-D tracking: its motion model with visual-odometry points, its
pose optimisation and its keyframe rules."""

from __future__ import annotations

import numpy as np
import pytest

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.geometry import project, transform
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.tracker import Tracker, TrackerConfig

ORBSLAM2 = TrackerConfig(motion_ransac=True)


def _run(path, tracker, filters=(), labels=False):
    seq = TumSequence(path, load_labels=labels)
    segmenter = LabelsSegmenter() if labels else NoSegmenter()
    pipeline = SlamPipeline(
        seq, segmenter, build_filters(list(filters)), tracker=tracker, progress=False
    )
    return seq, pipeline.run()


def test_the_removed_harness_policy_is_named() -> None:
    with pytest.raises(TypeError, match="policy"):
        TrackerConfig(policy="harness")  # type: ignore[call-arg]


def test_static_scene_is_tracked_within_2cm(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=30)
    seq, result = _run(path, ORBSLAM2)
    assert result.tracked == 30 and result.lost_events == 0
    assert ate(seq.groundtruth, result.trajectory).stats.rmse < 0.02
    _, again = _run(path, ORBSLAM2)  # deterministic
    np.testing.assert_array_equal(again.trajectory.positions, result.trajectory.positions)


def test_last_frame_gives_visual_odometry_points(synthetic_sequence) -> None:
    """After a frame that is not a keyframe, the motion model sees its map points and its
    close unmatched static keypoints back-projected with its pose (never its dynamic ones)."""
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=3))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    tracker = Tracker(TrackerConfig(min_new_points=0), ex)
    for i in range(2):
        frame = seq.load(i)
        feats = ex(frame.gray, frame.depth)
        dynamic = np.zeros(len(feats), bool)
        dynamic[: len(feats) // 4] = True  # a quarter of the keypoints flagged dynamic
        result = tracker.track(i, frame.stamp, feats, dynamic)
        kf = tracker.finish_frame(i, frame.stamp, result, feats, dynamic)
    assert kf is None  # frame 1 is not a keyframe
    world, _, _, map_ids = tracker._last_frame_points()
    vo = map_ids < 0
    assert vo.sum() > 20 and (~vo).sum() == (result.matched >= 0).sum()
    # VO points project exactly onto frame 1's keypoints with its pose, all static and close.
    cam = transform(tracker.last_pose_cw, world[vo])
    uv = project(tracker.k, cam)
    dist = np.linalg.norm(uv[:, None] - feats.uv[None], axis=2)
    nearest = dist.argmin(axis=1)
    assert dist.min(axis=1).max() < 1e-6
    assert not dynamic[nearest].any() and (result.matched[nearest] < 0).all()
    assert (cam[:, 2] <= tracker.config.th_depth + 1e-6).all()


def test_pose_optimisation_starts_with_every_match_an_inlier(synthetic_sequence) -> None:
    """A pose 5 cm off: the χ² test at that pose would reject most matches; ORB-SLAM2's rounds
    optimise on all of them first and recover the pose, rejecting only the corrupted ones."""
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=2))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frame = seq.load(0)
    feats = ex(frame.gray, frame.depth)
    tracker = Tracker(ORBSLAM2, ex)
    kp = np.flatnonzero(feats.has_depth)
    world = feats.points[kp].astype(np.float64)  # the camera at the origin
    rng = np.random.default_rng(0)
    bad = rng.choice(len(kp), len(kp) // 10, replace=False)
    world[bad] += rng.normal(0, 0.3, (len(bad), 3))
    start = np.eye(4)
    start[:3, 3] = [0.05, -0.03, 0.04]
    pose, inl = tracker.sampler.optimise_all(world, feats, kp, start)
    assert np.abs(pose[:3, 3]).max() < 0.005
    assert inl.sum() >= 0.85 * len(kp)
    assert inl[bad].mean() < 0.2


def test_masks_remove_most_of_the_walkers_error(synthetic_sequence) -> None:
    """The visual-odometry points re-create the walkers' keypoints on every frame, so they
    steer the unfiltered pose; ground-truth masks remove most of that error."""
    path = synthetic_sequence(preset="walking_xyz", frames=60, seed=3)
    seq, none = _run(path, ORBSLAM2)
    _, masked = _run(path, ORBSLAM2, filters=["semantic"], labels=True)
    e_none = ate(seq.groundtruth, none.trajectory).stats.rmse
    e_masked = ate(seq.groundtruth, masked.trajectory).stats.rmse
    assert masked.tracked == 60
    assert e_masked < 0.5 * e_none

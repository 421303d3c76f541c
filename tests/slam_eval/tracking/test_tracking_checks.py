"""What the tracker accepts: no zero-motion guess without a motion model, the doubled search
window and its width, a pose that fails its inlier check taken back, frames without depth never
posed, matches of one image rotation only."""

from __future__ import annotations

import shutil
from dataclasses import replace

import cv2
import numpy as np
import pytest

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import Features, OrbConfig, OrbExtractor
from uss_slam.slam_eval.matching.keyframe import match_keyframe
from uss_slam.slam_eval.matching.projection import rotation_consistent
from uss_slam.slam_eval.segmenters.base import NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.tracker import Tracker, TrackerConfig, TrackingState


@pytest.fixture(scope="module")
def static_frames(synthetic_sequence):
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=30))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frames = [seq.load(i) for i in range(len(seq))]
    return seq, ex, frames, [ex(f.gray, f.depth) for f in frames]


def _step(tracker: Tracker, frames, i: int, features: Features):
    dyn = np.zeros(len(features), bool)
    r = tracker.track(i, frames[i].stamp, features, dyn)
    tracker.finish_frame(i, frames[i].stamp, r, features, dyn)
    return r


def test_without_a_motion_model_a_failed_reference_match_relocalises(static_frames) -> None:
    # The second frame repeats the first: a zero-motion guess would track it at once. With the
    # reference keyframe's descriptor matching failing, the frame is lost and relocalised.
    _, ex, frames, feats = static_frames
    tracker = Tracker(TrackerConfig(), ex)
    _step(tracker, frames, 0, feats[0])
    calls = []

    def refuse(features, static):
        calls.append(len(features))
        return None, None

    tracker._track_reference = refuse
    r = _step(tracker, frames, 1, feats[0])
    assert calls == [len(feats[0])]  # no velocity: the reference keyframe was asked first
    assert r.state is TrackingState.OK and r.relocalised
    assert tracker.lost_events == 1 and tracker.relocalisations == 1


def test_the_motion_model_doubles_its_window_below_min_matches(static_frames) -> None:
    _, ex, frames, feats = static_frames
    tracker = Tracker(TrackerConfig(), ex)
    for i in range(3):
        assert _step(tracker, frames, i, feats[i]).state is TrackingState.OK
    assert tracker.velocity is not None
    match_points = tracker.projection.match_points
    radii = []

    def few_in_the_narrow_window(world, desc, level, pose, features, static, radius, angle):
        radii.append(radius)
        query, kp = match_points(world, desc, level, pose, features, static, radius, angle)
        if radius == tracker.config.search_radius:
            return query[:5], kp[:5]  # as if the camera had turned beyond the window
        return query, kp

    tracker.projection.match_points = few_in_the_narrow_window
    r = _step(tracker, frames, 3, feats[3])
    assert radii == [15.0, 30.0]
    assert r.state is TrackingState.OK and not r.relocalised


def _track_with_prediction_off(static_frames, search_radius: float, turn_px: float):
    """Frame 3's pose when the constant-velocity prediction is turned ``turn_px`` px off (a
    camera turning faster than it did the frame before)."""
    seq, ex, frames, feats = static_frames
    tracker = Tracker(TrackerConfig(search_radius=search_radius), ex)
    for i in range(3):
        assert _step(tracker, frames, i, feats[i]).state is TrackingState.OK
    turn = np.eye(4)
    turn[:3, :3] = cv2.Rodrigues(np.array([0.0, np.arctan(turn_px / seq.camera.fx), 0.0]))[0]
    tracker.velocity = turn @ tracker.velocity
    r = _step(tracker, frames, 3, feats[3])
    assert r.state is TrackingState.OK and not r.relocalised
    return r.pose_wc


def test_the_motion_model_window_keeps_a_pose_from_settling_near_the_prediction(
    static_frames,
) -> None:
    # ORB-SLAM2's RGB-D window (15 px) tracks a prediction 8 px off to the pose tracked from the
    # true prediction; a 7 px window finds only the matches near the wrong prediction and settles
    # millimetres towards it (on real frames turning 12° between frames: degrees).
    truth = _track_with_prediction_off(static_frames, 15.0, 0.0)
    wide = _track_with_prediction_off(static_frames, TrackerConfig().search_radius, 8.0)
    narrow = _track_with_prediction_off(static_frames, 7.0, 8.0)
    off = truth[:3, :3].T @ wide[:3, :3]
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(off)[0])) < 0.05
    assert np.linalg.norm(truth[:3, 3] - wide[:3, 3]) < 5e-4
    assert np.linalg.norm(truth[:3, 3] - narrow[:3, 3]) > 2e-3


def test_a_pose_failing_its_inlier_check_is_lost_and_not_mapped(static_frames) -> None:
    _, ex, frames, feats = static_frames
    tracker = Tracker(TrackerConfig(), ex)
    for i in range(6):
        assert _step(tracker, frames, i, feats[i]).state is TrackingState.OK
    keyframes, found = len(tracker.map.keyframes), tracker.map.points.found.view.copy()
    f = feats[6]
    dyn = np.zeros(len(f), bool)
    r = tracker.track(6, frames[6].stamp, f, dyn)
    assert r.state is TrackingState.OK and r.inliers >= 30
    # The post-pose filters drop all but 10 of its matched keypoints.
    drop = r.matched >= 0
    drop[np.flatnonzero(drop)[:10]] = False
    pose_wc, matched = tracker.refine_without(r.pose_wc, f, r.matched, drop)
    assert pose_wc is None and (matched < 0).all()
    tracker.mark_lost(r)
    assert r.pose_wc is None and r.state is TrackingState.LOST and r.inliers == 0
    assert tracker.finish_frame(6, frames[6].stamp, r, f, drop) is None
    assert len(tracker.map.keyframes) == keyframes
    np.testing.assert_array_equal(tracker.map.points.found.view, found)
    assert tracker.lost_events == 1
    r = _step(tracker, frames, 7, feats[7])  # the next frame relocalises
    assert r.state is TrackingState.OK and r.relocalised
    # Dropping a few keypoints only: refined without them, still tracked.
    r = tracker.track(8, frames[8].stamp, feats[8], np.zeros(len(feats[8]), bool))
    drop = np.zeros(len(feats[8]), bool)
    drop[np.flatnonzero(r.matched >= 0)[:5]] = True
    pose_wc, matched = tracker.refine_without(r.pose_wc, feats[8], r.matched, drop)
    assert pose_wc is not None and (matched[drop] < 0).all()
    assert (matched >= 0).sum() >= TrackerConfig().min_inliers


def test_frames_without_depth_are_not_posed_and_counted(synthetic_sequence, tmp_path, capsys):
    path = tmp_path / "seq"
    shutil.copytree(synthetic_sequence(preset="static_xyz", frames=30), path)
    seq = TumSequence(path)
    for i in (10, 11, 12):
        depth = seq.records[i].depth_path
        cv2.imwrite(str(depth), np.zeros_like(cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)))
    result = SlamPipeline(TumSequence(path), NoSegmenter(), build_filters([]), progress=False).run()
    tracked = {e.index: e.tracked for e in result.log}
    assert not any(tracked[i] for i in (10, 11, 12))
    assert all(tracked[i] for i in range(10)) and tracked[29]
    assert result.tracked == 27 and len(result.trajectory.stamps) == 27
    err = capsys.readouterr().err
    assert f"{path}: 3 frame(s) with an all-zero depth image (frame index 10 first)" in err


def test_matches_of_an_inconsistent_image_rotation_are_dropped() -> None:
    # 60 true matches whose keypoints turned by 40 degrees (±2), 30 wrong ones at random angles:
    # ORB-SLAM2's rotation histogram keeps the bin of 40 degrees and at most two others.
    rng = np.random.default_rng(0)
    reference = rng.uniform(0, 360, 90)
    turn = np.r_[40 + rng.uniform(-2, 2, 60), rng.uniform(0, 360, 30)]
    angle = np.mod(reference - turn, 360)
    keep = rotation_consistent(reference, angle)
    assert keep[:60].all()
    assert keep[60:].sum() <= 6  # wrong matches in the kept bins only
    wrapped = rotation_consistent(np.array([359.0, 1.0, 2.0]), np.array([1.0, 3.0, 4.0]))
    assert wrapped.all()  # -2 degrees = 358: one bin across the wrap
    assert rotation_consistent(np.zeros(0), np.zeros(0)).shape == (0,)


def test_the_reference_keyframe_match_checks_the_rotation(static_frames) -> None:
    _, ex, frames, feats = static_frames
    tracker = Tracker(TrackerConfig(), ex)
    _step(tracker, frames, 0, feats[0])
    kf = tracker.map.keyframes[0]
    f = feats[0]
    query = np.arange(len(f))
    plain = match_keyframe(tracker.map, f, query, kf, 0.7, 100, 15)
    # The same frame with a third of its keypoint angles scrambled: those matches are dropped
    # (but for the few whose random turn falls in a kept bin).
    scrambled = replace(f, angle=f.angle.copy())
    bad = np.arange(len(f)) % 3 == 0
    turn = np.random.default_rng(0).uniform(0, 360, bad.sum())
    scrambled.angle[bad] = np.mod(f.angle[bad] - turn, 360)
    checked = match_keyframe(tracker.map, scrambled, query, kf, 0.7, 100, 15, True)
    unchecked = match_keyframe(tracker.map, scrambled, query, kf, 0.7, 100, 15, False)
    np.testing.assert_array_equal(unchecked[0], plain[0])
    good_before, bad_before = (~bad[plain[0]]).sum(), bad[plain[0]].sum()
    assert bad_before > 100
    assert (~bad[checked[0]]).sum() >= 0.95 * good_before
    assert bad[checked[0]].sum() <= 0.1 * bad_before

"""Tracker on synthetic sequences: accuracy, keyframes and map, relocalisation, dynamic scenes."""

from __future__ import annotations

import numpy as np
import pytest

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import Features, OrbConfig, OrbExtractor
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.tracker import Tracker, TrackerConfig, TrackingState


def _run(path, filters=(), labels=False, **kwargs):
    seq = TumSequence(path, load_labels=labels)
    segmenter = LabelsSegmenter() if labels else NoSegmenter()
    result = SlamPipeline(
        seq, segmenter, build_filters(list(filters)), progress=False, **kwargs
    ).run()
    return seq, result


def test_static_scene_is_tracked_within_2cm(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=30)
    seq, result = _run(path)
    assert result.frames == 30 and result.tracked == 30 and result.tracked_fraction == 1.0
    assert result.relocalisations == 0 and result.lost_events == 0
    assert result.keyframes >= 1 and result.map_points > 100
    assert result.keypoints["extracted"] == sum(e.keypoints for e in result.log)
    assert result.keypoints["kept"] == result.keypoints["extracted"]  # no filters
    error = ate(seq.groundtruth, result.trajectory)
    assert error.stats.pairs == 30
    assert error.stats.rmse < 0.02
    # Deterministic: the same input gives the same trajectory.
    _, again = _run(path, prefetch=0)
    np.testing.assert_array_equal(again.trajectory.positions, result.trajectory.positions)


def test_relocalises_after_losing_track(synthetic_sequence) -> None:
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=30))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frames = [seq.load(i) for i in range(len(seq))]
    feats = [ex(f.gray, f.depth) for f in frames]

    def step(tracker: Tracker, i: int, features: Features):
        dyn = np.zeros(len(features), bool)
        r = tracker.track(i, frames[i].stamp, features, dyn)
        tracker.finish_frame(i, frames[i].stamp, r, features, dyn)
        return r

    reference = Tracker(TrackerConfig(), ex)
    poses = [step(reference, i, feats[i]).pose_wc for i in range(len(frames))]

    tracker = Tracker(TrackerConfig(), ex)
    for i in range(12):
        assert step(tracker, i, feats[i]).state is TrackingState.OK
    for i in range(12, 18):  # camera covered: nothing to match
        r = step(tracker, i, Features.empty())
        assert r.state is TrackingState.LOST and r.pose_wc is None
    assert tracker.lost_events == 1
    r = step(tracker, 22, feats[22])  # uncovered 10 frames later, far from the motion model
    assert r.state is TrackingState.OK and r.relocalised
    assert tracker.relocalisations == 1
    assert np.linalg.norm(r.pose_wc[:3, 3] - poses[22][:3, 3]) < 0.01
    assert step(tracker, 23, feats[23]).state is TrackingState.OK


def test_second_frame_is_matched_to_the_reference_keyframe(synthetic_sequence) -> None:
    # A camera already moving when tracking starts: the second frame has no motion model, and
    # projecting with the first pose misses most matches once the view moved beyond the window.
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=30))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    first, later = seq.load(0), seq.load(24)
    f0, f1 = ex(first.gray, first.depth), ex(later.gray, later.depth)

    def second_frame(config: TrackerConfig):
        tracker = Tracker(config, ex)
        for i, (frame, feats) in enumerate(((first, f0), (later, f1))):
            dyn = np.zeros(len(feats), bool)
            r = tracker.track(i, frame.stamp, feats, dyn)
            tracker.finish_frame(i, frame.stamp, r, feats, dyn)
        return r

    by_reference = second_frame(TrackerConfig())
    assert by_reference.state is TrackingState.OK
    # This render's 24 frames move the view beyond 7 and 4 px windows (the motion model's and the
    # local map's before they became ORB-SLAM2's RGB-D 15 and 12), not beyond the defaults.
    narrow = {"search_radius": 7.0, "local_radius": 4.0}
    by_projection = second_frame(TrackerConfig(reference_keyframe=False, **narrow))
    assert second_frame(TrackerConfig(**narrow)).inliers > by_projection.inliers
    truth = seq.groundtruth
    near = [int(np.argmin(np.abs(truth.stamps - f.stamp))) for f in (first, later)]
    poses = truth.matrices()
    moved = np.linalg.inv(poses[near[0]]) @ poses[near[1]]  # the first frame is the origin
    assert np.linalg.norm(moved[:3, 3]) > 0.02  # the view did move
    assert np.linalg.norm(by_reference.pose_wc[:3, 3] - moved[:3, 3]) < 0.02  # of 12 cm


def test_relocalises_against_the_best_matching_keyframe_not_the_latest(synthetic_sequence) -> None:
    # As when a walker comes close (walking_xyz seed 1): while the left of the view is hidden,
    # several keyframes are made that hold points on the right only; after an occlusion only the
    # left is visible again. Those latest keyframes (which are also the nearest to the last pose)
    # match nothing; the first keyframes, which saw the whole view, do.
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=30))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frames = [seq.load(i) for i in range(len(seq))]
    feats = [ex(f.gray, f.depth) for f in frames]
    width = seq.camera.width

    def step(tracker: Tracker, i: int, features: Features, dyn: np.ndarray | None = None):
        dyn = np.zeros(len(features), bool) if dyn is None else dyn
        r = tracker.track(i, frames[i].stamp, features, dyn)
        tracker.finish_frame(i, frames[i].stamp, r, features, dyn)
        return r

    reference = Tracker(TrackerConfig(), ex)
    poses = [step(reference, i, feats[i]).pose_wc for i in range(len(frames))]

    # Asking for more tracked close points than a frame holds (and any untracked one) makes
    # ORB-SLAM2's close-point rule hold on most frames, which builds the right-only keyframes of
    # the scenario.
    config = TrackerConfig(reloc_keyframes=2, min_close_tracked=1000, min_close_untracked=0)
    tracker = Tracker(config, ex)
    for i in range(6):
        assert step(tracker, i, feats[i]).state is TrackingState.OK
    first = len(tracker.map.keyframes)
    for i in range(6, 14):  # left 60% hidden
        hidden = feats[i].xy[:, 0] < 0.6 * width
        assert step(tracker, i, feats[i], hidden).state is TrackingState.OK
    kfs = tracker.map.keyframes
    assert len(kfs) - first >= 3  # more right-only keyframes than reloc_keyframes
    for kf in kfs[first:]:
        seen = kf.point_ids >= 0
        assert np.all(kf.features.xy[seen, 0] >= 0.6 * width)
    for i in range(14, 18):  # covered
        assert step(tracker, i, Features.empty()).state is TrackingState.LOST
    hidden = feats[20].xy[:, 0] >= 0.4 * width  # only the left 40% visible
    r = step(tracker, 20, feats[20], hidden)
    assert r.state is TrackingState.OK and r.relocalised
    assert r.inliers >= TrackerConfig().reloc_min_inliers
    # 40% of a 320x240 view: within the 2 cm of the static target (measured 1.1 cm).
    assert np.linalg.norm(r.pose_wc[:3, 3] - poses[20][:3, 3]) < 0.02


def test_more_inliers_needed_right_after_a_relocalisation(synthetic_sequence) -> None:
    # ORB-SLAM2's TrackLocalMap: within reloc_recent_frames of a relocalisation a frame needs
    # reloc_min_inliers, not min_inliers. The same weak frame (left quarter of the view only) is
    # tracked when the rule is off or the relocalisation is old, and rejected right after it.
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=30))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frames = [seq.load(i) for i in range(len(seq))]
    feats = [ex(f.gray, f.depth) for f in frames]
    hidden = feats[23].xy[:, 0] >= 0.25 * seq.camera.width

    def run(config: TrackerConfig, weak_index: int):
        tracker = Tracker(config, ex)
        for i in range(30):
            if i in range(12, 18):
                features, dyn = Features.empty(), np.zeros(0, bool)  # covered: lost
            elif i in range(18, 22) or i > 23:
                continue
            else:
                features = feats[i]
                dyn = hidden if i == 23 else np.zeros(len(features), bool)
            index = weak_index if i == 23 else i
            r = tracker.track(index, frames[i].stamp, features, dyn)
            tracker.finish_frame(index, frames[i].stamp, r, features, dyn)
            if i == 22:
                assert r.relocalised and tracker.last_relocalisation == 22
        return tracker, r

    off, r_off = run(TrackerConfig(reloc_recent_frames=0), 23)
    n = r_off.inliers
    assert r_off.state is TrackingState.OK and not r_off.relocalised
    assert TrackerConfig().min_inliers <= n and off.lost_events == 1
    strict = TrackerConfig(reloc_min_inliers=n + 1, reloc_recent_frames=30)
    on, r_on = run(strict, 23)
    assert r_on.pose_wc is None or r_on.relocalised  # not accepted from the motion model
    assert on.lost_events == 2
    later, r_later = run(strict, 22 + 30)  # the same frame once the window has passed
    assert r_later.state is TrackingState.OK and not r_later.relocalised
    assert r_later.inliers == n and later.lost_events == 1


def test_start_as_relocalisation_holds_the_first_frames_to_fifty_inliers(
    synthetic_sequence,
) -> None:
    # slam.tracker.start_as_relocalisation=true: as ORB-SLAM2 (mnLastRelocFrameId starts at
    # frame 0), the first frames need reloc_min_inliers, as after a relocalisation. A weak frame
    # (left quarter of the view) early on is refused; by default, or 30 frames later, it is not.
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=12))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frames = [seq.load(i) for i in range(len(seq))]
    feats = [ex(f.gray, f.depth) for f in frames]
    hidden = feats[6].xy[:, 0] >= 0.25 * seq.camera.width

    def run(config: TrackerConfig, offset: int = 0):
        tracker = Tracker(config, ex)
        for i in range(7):
            dyn = hidden if i == 6 else np.zeros(len(feats[i]), bool)
            index = i + offset if i > 0 else 0
            r = tracker.track(index, frames[i].stamp, feats[i], dyn)
            tracker.finish_frame(index, frames[i].stamp, r, feats[i], dyn)
        return tracker, r

    off, r_off = run(TrackerConfig())
    n = r_off.inliers
    assert r_off.state is TrackingState.OK and n >= TrackerConfig().min_inliers
    assert off.last_relocalisation is None and off.lost_events == 0
    strict = TrackerConfig(start_as_relocalisation=True, reloc_min_inliers=n + 1)
    on, r_on = run(strict)
    assert r_on.pose_wc is None or r_on.relocalised  # not accepted from the motion model
    assert on.lost_events == 1
    assert on.last_relocalisation == (6 if r_on.relocalised else 0)
    later, r_later = run(strict, offset=30)  # the same frames once the window has passed
    assert r_later.state is TrackingState.OK and r_later.inliers == n
    assert later.lost_events == 0


def _orbslam2_local_radius(frame_id: int, last_reloc_id: int | None) -> float:
    """ORB-SLAM2's Tracking::SearchLocalPoints for RGB-D, restated: ``th = 3;
    if (mCurrentFrame.mnId < mnLastRelocFrameId + 2) th = 5;`` and the window
    RadiusByViewingCos (4 away from frontal views) × th. ``last_reloc_id`` None: no
    relocalisation yet (ORB-SLAM2 starts it at frame 0; here the start is no relocalisation)."""
    th = 3
    if last_reloc_id is not None and frame_id < last_reloc_id + 2:
        th = 5
    return 4.0 * th


@pytest.mark.parametrize(
    ("overrides", "wide_radius", "wide_frames"),
    [({}, 20.0, 2), ({"reloc_local_frames": 0}, None, 0), ({"reloc_local_frames": 3}, 20.0, 3)],
)
def test_the_local_map_window_is_wider_right_after_a_relocalisation(
    synthetic_sequence, overrides, wide_radius, wide_frames
) -> None:
    # Frames 0-11 tracked, 12-17 covered (lost), then frames 22-29 of the render, which the
    # motion model cannot reach: the first of them relocalises. Frame ids run on without a gap,
    # as ORB-SLAM2's mnId.
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=30))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frames = [seq.load(i) for i in range(len(seq))]
    render = list(range(12)) + [None] * 6 + list(range(22, 30))
    tracker = Tracker(TrackerConfig(**overrides), ex)
    radii: list[tuple[int, float]] = []
    match = tracker.projection.match_map_points

    def spy(point_ids, pose_cw, features, available, radius, local=False):
        if local:
            radii.append((tracker._current_index, radius))
        return match(point_ids, pose_cw, features, available, radius, local)

    tracker.projection.match_map_points = spy
    relocalised = []
    for frame_id, i in enumerate(render):
        frame = frames[0 if i is None else i]
        features = Features.empty() if i is None else ex(frame.gray, frame.depth)
        dyn = np.zeros(len(features), bool)
        r = tracker.track(frame_id, frame.stamp, features, dyn)
        tracker.finish_frame(frame_id, frame.stamp, r, features, dyn)
        assert (r.state is TrackingState.OK) == (i is not None), frame_id
        if r.relocalised:
            relocalised.append(frame_id)
    assert relocalised == [18] and tracker.lost_events == 1
    # Every tracked frame but the first keyframe searched the local map, the lost ones did not.
    assert sorted({f for f, _ in radii}) == list(range(1, 12)) + list(range(18, 26))
    for frame_id, radius in radii:
        if wide_radius is None:
            assert radius == TrackerConfig().local_radius, frame_id
        elif wide_frames == 2:  # the defaults: ORB-SLAM2's rule itself
            assert radius == _orbslam2_local_radius(frame_id, 18 if frame_id >= 18 else None)
        else:
            wide = 18 <= frame_id < 18 + wide_frames
            assert radius == (wide_radius if wide else TrackerConfig().local_radius), frame_id
    assert {f for f, r in radii if r == 20.0} == set(range(18, 18 + wide_frames))


@pytest.mark.parametrize(
    ("key", "value", "line"),
    [
        ("reloc_local_radius", 0.0, "reloc_local_radius: expected a number > 0, got 0.0"),
        ("reloc_local_frames", -1, "reloc_local_frames: expected an integer >= 0, got -1"),
    ],
)
def test_a_bad_relocalisation_window_names_its_key(key, value, line) -> None:
    with pytest.raises(ValueError) as caught:
        TrackerConfig(**{key: value})
    assert str(caught.value) == line


def test_not_enough_depth_to_initialise(synthetic_sequence) -> None:
    seq = TumSequence(synthetic_sequence(preset="static_xyz", frames=30))
    ex = OrbExtractor(OrbConfig(), seq.camera)
    frame = seq.load(0)
    features = ex(frame.gray, np.zeros_like(frame.depth))  # no depth at all
    tracker = Tracker(TrackerConfig(), ex)
    r = tracker.track(0, frame.stamp, features, np.zeros(len(features), bool))
    assert r.state is TrackingState.NOT_INITIALIZED and r.pose_wc is None
    assert not tracker.map.keyframes


@pytest.mark.slow
def test_semantic_filter_beats_the_baseline_on_a_walking_sequence(synthetic_sequence) -> None:
    # At the target's 640x480: at 320x240 the walkers (up to ~60% of the view) leave the
    # filtered run too few keypoints for a while and it loses track (known, see the README).
    path = synthetic_sequence(preset="walking_xyz", frames=120, size=(640, 480))
    seq, baseline = _run(path, labels=True)
    _, semantic = _run(path, ["semantic"], labels=True)
    assert baseline.tracked_fraction == 1.0 and semantic.tracked_fraction == 1.0
    assert semantic.keypoints["dropped"]["semantic"] > 0.05 * semantic.keypoints["extracted"]
    base = ate(seq.groundtruth, baseline.trajectory).stats.rmse
    filtered = ate(seq.groundtruth, semantic.trajectory).stats.rmse
    assert filtered < 0.02
    assert filtered < 0.5 * base


@pytest.mark.slow
def test_semantic_filter_costs_nothing_on_a_static_scene(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=120)
    seq, baseline = _run(path, labels=True)
    _, semantic = _run(path, ["semantic"], labels=True)
    base = ate(seq.groundtruth, baseline.trajectory).stats.rmse
    filtered = ate(seq.groundtruth, semantic.trajectory).stats.rmse
    assert base < 0.02
    # The people of static_xyz sit still: dropping their keypoints only removes information.
    # At 320x240 over 4 s the run-to-run spread is larger than at the 640x480 / 300-frame size of
    # the target (<= 10% worse, studies/slam_targets.py), hence 25% here.
    assert filtered <= 1.25 * base

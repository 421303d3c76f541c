"""``slam.mask_max_age_s``: once the carried mask is older than that, a tracked frame that is no
keyframe asks the idle semantic thread for its own mask, which is carried from the frame's pose
on its reference keyframe and marks bad the map points the frame matched on its people."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.config import check
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.segmenters.base import ImageSegmenter, LabelsSegmenter
from uss_slam.slam_eval.sequence import Frame, TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.systems.semantic_thread import (
    CarriedMask,
    Delivered,
    SimulatedThread,
    WallThread,
    frame_mask,
    mark_matched,
    start_thread,
)

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _frame(index: int, stamp: float, labels: np.ndarray | None = None) -> Frame:
    h, w = (480, 640) if labels is None else labels.shape
    rgb = np.zeros((h, w, 3), np.uint8)
    return Frame(index, stamp, rgb, rgb[..., 0], np.full((h, w), 2.0, np.float32), labels)


def _person_ahead() -> np.ndarray:
    labels = np.zeros((480, 640), np.uint8)
    labels[200:280, 280:360] = 1
    return labels


def _map(n_points: int, poses: dict[int, np.ndarray]) -> SimpleNamespace:
    """The parts of a map the frame's mask uses: keyframe poses and the points' bad flags."""
    points = SimpleNamespace(bad=SimpleNamespace(view=np.zeros(n_points, bool)))
    return SimpleNamespace(points=points, pose_wc=lambda kf_id: poses[kf_id])


def test_a_frame_request_is_delivered_with_its_anchor_and_counted_apart() -> None:
    thread = start_thread(LabelsSegmenter(latency_s=0.1))
    assert isinstance(thread, SimulatedThread) and thread.idle()
    anchor = (3, np.eye(4))
    xy, matched = np.zeros((2, 2)), np.array([4, -1])
    thread.request_frame(_frame(7, 0.0, _person_ahead()), anchor, xy, matched)
    assert not thread.idle()  # segmenting it
    assert thread.poll(0.05) == []
    (got,) = thread.poll(0.1)
    assert thread.idle()
    assert (got.kf_id, got.anchor, got.requested, got.delivered) == (-1, anchor, 0.0, 0.1)
    assert got.xy is xy and got.matched is matched and got.labels is not None
    stats = thread.stats.as_dict()
    assert (stats["requested"], stats["frames_requested"], stats["delivered"]) == (0, 1, 1)
    # a keyframe asked for while the frame is segmented waits, and replaces nothing
    thread.request_frame(_frame(8, 0.2, _person_ahead()), anchor, xy, matched)
    thread.request(_frame(9, 0.25, _person_ahead()), kf_id=4)
    assert [d.kf_id for d in thread.poll(0.3)] == [-1]
    assert [d.kf_id for d in thread.poll(0.4)] == [4]
    assert thread.stats.skipped == 0


class _Slow(ImageSegmenter):
    """Answers once released."""

    name = "slow"

    def __init__(self) -> None:
        self.release = threading.Event()

    def infer(self, rgb: np.ndarray) -> np.ndarray:
        self.release.wait(30.0)
        return np.zeros(rgb.shape[:2], np.uint8)


def test_the_wall_thread_is_busy_while_it_segments() -> None:
    seg = _Slow()
    thread = start_thread(seg)
    assert isinstance(thread, WallThread) and thread.idle()
    thread.request_frame(_frame(0, 0.0), (0, np.eye(4)), np.zeros((0, 2)), np.zeros(0, np.int64))
    assert not thread.idle()
    seg.release.set()
    deadline, got = time.perf_counter() + 5.0, []
    while not got and time.perf_counter() < deadline:
        got = thread.poll(1.0)
        time.sleep(0.01)
    thread.close()
    assert [d.kf_id for d in got] == [-1] and thread.idle()


def test_a_frame_mask_is_carried_from_the_frame_on_its_keyframe() -> None:
    """The mask follows the reference keyframe when the back end moves it."""
    t_c_kf = np.eye(4)
    t_c_kf[0, 3] = -0.4  # the frame stood 0.4 m right of keyframe 2
    moved = np.eye(4)
    moved[1, 3] = 0.1  # the back end then moved keyframe 2 down by 0.1 m
    slam_map = _map(10, {2: moved})
    got = Delivered(-1, _frame(5, 1.0), _person_ahead(), 1.0, anchor=(2, t_c_kf))
    got.xy = np.array([[320.0, 240.0], [320.0, 240.0], [600.0, 50.0], [50.0, 400.0]])
    got.matched = np.array([3, 3, 4, -1])
    carried, marked = frame_mask(slam_map, got, got.labels > 0, K)
    assert marked == 1 and slam_map.points.bad.view.tolist() == [i == 3 for i in range(10)]
    assert carried.kf_id == -1 and carried.stamp == 1.0
    frame_pose = moved @ np.linalg.inv(t_c_kf)
    np.testing.assert_allclose(carried.source_pose(slam_map), frame_pose)
    # seen from where the frame was, the person is where the frame saw it
    seen = carried.labels_for(slam_map, frame_pose) > 0
    person = _person_ahead() > 0
    assert (seen & person).sum() / (seen | person).sum() > 0.9
    # a keyframe's own mask is carried from the keyframe
    own = CarriedMask.of(2, _person_ahead(), np.full((480, 640), 2.0, np.float32), K)
    np.testing.assert_allclose(own.source_pose(slam_map), moved)


def test_mark_matched_marks_only_good_points_inside_the_region() -> None:
    slam_map = _map(6, {})
    slam_map.points.bad.view[2] = True
    region = _person_ahead() > 0
    xy = np.array([[300.0, 220.0], [310.0, 230.0], [300.0, 250.0], [10.0, 10.0], [320.0, 240]])
    assert mark_matched(slam_map, region, xy, np.array([1, 1, 2, 5, -1])) == 1
    assert slam_map.points.bad.view.tolist() == [False, True, True, False, False, False]


def _run(path: Path, **keys: object):
    """A fast segmenter (0.05 s): the thread is idle between keyframes."""
    seq = TumSequence(path, load_labels=True)
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=0.05), build_filters(["semantic"]),
        segment="thread", progress=False, local_ba=True, **keys,
    ).run()  # fmt: skip


def test_stale_masks_ask_for_frames_end_to_end(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    off, on = _run(path), _run(path, mask_max_age_s=0.04)
    again = _run(path, mask_max_age_s=0.04)
    assert off.semantic_thread is not None and on.semantic_thread is not None
    assert off.semantic_thread["frames_requested"] == 0
    assert on.semantic_thread["frames_requested"] > 0
    assert on.semantic_thread["frame_masks"] > 0
    np.testing.assert_array_equal(on.trajectory.positions, again.trajectory.positions)
    assert not np.array_equal(on.trajectory.positions, off.trajectory.positions)
    # an age no mask reaches in 40 frames: today's run to the last digit
    never = _run(path, mask_max_age_s=100.0)
    assert never.semantic_thread is not None and never.semantic_thread["frames_requested"] == 0
    np.testing.assert_array_equal(never.trajectory.positions, off.trajectory.positions)


def test_the_key_is_off_by_default_and_refuses_a_non_positive_age(
    synthetic_sequence, tmp_path: Path
) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    slam = slam_run_config(path, tmp_path / "a", "segmenter=labels", "filters=[semantic]").slam
    assert slam.mask_max_age_s is None
    with pytest.raises(UssSlamError, match="mask_max_age_s"):
        check(slam_run_config(path, tmp_path / "b", "slam.mask_max_age_s=0"))

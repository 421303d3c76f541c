"""``segment=thread``: the semantic thread off the tracking path, the mask carried by the tracked
pose, the oracle's latency option, and a tiny end-to-end run."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.config import check
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.segmenters.base import ImageSegmenter, LabelsSegmenter
from uss_slam.slam_eval.sequence import Frame, TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.systems.semantic_thread import (
    CarriedMask,
    SimulatedThread,
    WallThread,
    fill_depth,
    start_thread,
)

PERSON = CLASS_NAMES.index("person")
K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _frame(index: int, stamp: float, labels: np.ndarray | None = None) -> Frame:
    h, w = (48, 64) if labels is None else labels.shape
    rgb = np.zeros((h, w, 3), np.uint8)
    return Frame(index, stamp, rgb, rgb[..., 0], np.ones((h, w), np.float32), labels)


def _square_on_plane(t_frame_kf: np.ndarray) -> np.ndarray:
    """(480, 640) bool: where a 0.4 m square on the plane z = 2 m (keyframe camera: centred on
    x = 0.2 m, y = 0) is seen from a camera at ``T_frame,kf`` (exact, per pixel: the ray of
    each pixel meets the plane)."""
    h, w = 480, 640
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    t_kf_frame = np.linalg.inv(t_frame_kf)
    dirs = rays @ t_kf_frame[:3, :3].T
    origin = t_kf_frame[:3, 3]
    s = (2.0 - origin[2]) / dirs[..., 2]
    x = origin[0] + s * dirs[..., 0]
    y = origin[1] + s * dirs[..., 1]
    return (np.abs(x - 0.2) <= 0.2) & (np.abs(y) <= 0.2)


def _pose(yaw_deg: float, tx: float, tz: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    t = np.eye(4)
    t[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    t[:3, 3] = [tx, 0.0, tz]
    return t


@pytest.mark.parametrize("t_frame_kf", [_pose(0, -0.15, 0.0), _pose(6, 0.05, -0.3)])
def test_carried_mask_lands_where_the_truth_is(t_frame_kf: np.ndarray) -> None:
    labels = np.where(_square_on_plane(np.eye(4)), PERSON, 0).astype(np.uint8)
    depth = np.full(labels.shape, 2.0, np.float32)
    carried = CarriedMask.of(3, labels, depth, K).labels_at(t_frame_kf) == PERSON
    truth = _square_on_plane(t_frame_kf)
    stale = labels == PERSON
    iou = (carried & truth).sum() / (carried | truth).sum()
    assert iou > 0.9
    assert (stale & truth).sum() / (stale | truth).sum() < 0.75  # the motion mattered


def test_carried_mask_leaves_out_pixels_without_depth_or_behind_the_camera() -> None:
    labels = np.full((480, 640), PERSON, np.uint8)
    depth = np.zeros(labels.shape, np.float32)
    assert not CarriedMask.of(0, labels, depth, K).labels_at(np.eye(4)).any()
    depth[:] = 1.0
    behind = _pose(180, 0, 0)
    assert not CarriedMask.of(0, labels, depth, K).labels_at(behind).any()


def test_fill_depth_fills_the_holes_of_each_labelled_region() -> None:
    labels = np.zeros((20, 30), np.uint8)
    labels[2:8, 2:8] = PERSON  # measured in part: its holes take its median
    labels[12:18, 20:28] = PERSON  # measured nowhere (too close): the frame's nearest depth
    depth = np.full(labels.shape, 3.0, np.float32)
    depth[2:8, 2:8] = np.linspace(1.0, 2.0, 36).reshape(6, 6)
    depth[2:4, 2:4] = 0.0
    depth[12:18, 20:28] = 0.0
    depth[0, 29] = 0.0  # a hole outside any label stays a hole
    depth[19, 0:10] = 0.5  # the nearest measured depths
    out = fill_depth(labels, depth)
    measured = depth[2:8, 2:8][depth[2:8, 2:8] > 0]
    np.testing.assert_allclose(out[2:4, 2:4], np.median(measured))
    np.testing.assert_array_equal(out[4:8, 4:8], depth[4:8, 4:8])
    np.testing.assert_allclose(out[12:18, 20:28], np.percentile(depth[depth > 0], 1))
    assert out[0, 29] == 0.0 and depth[2, 2] == 0.0  # the input is left as it was


def test_carried_mask_keeps_a_person_whose_depth_has_holes() -> None:
    labels = np.where(_square_on_plane(np.eye(4)), PERSON, 0).astype(np.uint8)
    depth = np.full(labels.shape, 2.0, np.float32)
    depth[labels > 0] = 0.0  # the person nearer than the sensor's range: no depth on it
    depth[(labels > 0) & (np.arange(640)[None, :] % 3 == 0)] = 2.0  # except a few columns
    carried = CarriedMask.of(0, labels, depth, K).labels_at(np.eye(4)) == PERSON
    truth = labels == PERSON
    assert (carried & truth).sum() / (carried | truth).sum() > 0.9


def test_simulated_thread_delivers_after_the_latency_newest_waiting_first() -> None:
    seg = LabelsSegmenter(latency_s=0.1)
    thread = start_thread(seg)
    assert isinstance(thread, SimulatedThread) and thread.clock == "camera"
    labels = np.zeros((48, 64), np.uint8)
    stamps = np.arange(20) / 30.0
    thread.request(_frame(0, stamps[0], labels), kf_id=0)
    got = []
    for i, t in enumerate(stamps[1:], start=1):
        got += [(i, d.kf_id) for d in thread.poll(t)]
        if i in (1, 2, 3):  # three keyframes while the first one is segmented
            thread.request(_frame(i, t, labels), kf_id=i)
    # Keyframe 0 ends 0.1 s after stamp 0 (frame 3); keyframe 2 replaced 1 while waiting and
    # starts then (0.1 -> 0.2 s, frame 6); keyframe 3, asked for after frame 3's poll, follows.
    assert got == [(3, 0), (6, 2), (9, 3)]
    assert thread.stats.as_dict()["skipped"] == 1
    assert thread.stats.as_dict()["mean_delay_s"] == pytest.approx((0.1 + 0.2 - 1 / 15 + 0.2) / 3)


class NeverAnswers(ImageSegmenter):
    """Blocks every call until released (or 30 s): a segmenter far slower than the run;
    with ``answer_first`` the first call answers at once."""

    name = "never"

    def __init__(self, answer_first: bool = False) -> None:
        self.release = threading.Event()
        self.calls = 0
        self.answer_first = answer_first

    def infer(self, rgb: np.ndarray) -> np.ndarray:
        self.calls += 1
        if not (self.answer_first and self.calls == 1):
            self.release.wait(30.0)
        return np.zeros(rgb.shape[:2], np.uint8)


def test_wall_thread_never_blocks_the_caller() -> None:
    seg = NeverAnswers()
    thread = start_thread(seg)
    assert isinstance(thread, WallThread)
    start = time.perf_counter()
    for i in range(5):
        thread.request(_frame(i, i / 30.0), kf_id=i)
        assert thread.poll(i / 30.0) == []
    assert time.perf_counter() - start < 0.5
    seg.release.set()
    deadline = time.perf_counter() + 5.0
    got: list = []
    while 4 not in [d.kf_id for d in got] and time.perf_counter() < deadline:
        got += thread.poll(1.0)
        time.sleep(0.01)
    thread.close()
    # The keyframe the thread took while the others came (whichever had come: the thread
    # starts when the machine lets it), then only the newest one.
    ids = [d.kf_id for d in got]
    assert ids[-1] == 4 and len(ids) <= 2 and ids == sorted(set(ids))
    assert got[-1].labels is not None


def test_tracking_never_waits_for_the_semantic_thread(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    seg = NeverAnswers(answer_first=True)  # only the first keyframe's mask is waited for
    seq = TumSequence(path)
    start = time.perf_counter()
    result = SlamPipeline(
        seq, seg, build_filters(["semantic"]), segment="thread", progress=False
    ).run()
    seg.release.set()
    assert time.perf_counter() - start < 25.0  # it did not wait for the 30 s call
    assert seg.calls == 2 and result.segmented_frames == 1  # the first mask, in the loop
    assert result.tracked == 30 and result.semantic_thread is not None
    stats = result.semantic_thread
    assert stats["clock"] == "wall" and stats["first_wait_s"] >= 0.0
    assert stats["requested"] == result.keyframes - 1  # every keyframe but the first


def _thread_run(path: Path, latency: float, filters=("semantic",)):
    seq = TumSequence(path, load_labels=True)
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=latency), build_filters(list(filters)),
        segment="thread", progress=False,
    ).run()  # fmt: skip


def test_thread_schedule_end_to_end_is_deterministic_and_filters(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    a, b = _thread_run(path, 0.2), _thread_run(path, 0.2)
    np.testing.assert_array_equal(a.trajectory.positions, b.trajectory.positions)
    stats = a.semantic_thread
    assert stats is not None and stats["clock"] == "camera"
    assert stats["delivered"] + 1 == a.segmented_frames >= 3  # + the first keyframe's
    assert stats["first_wait_s"] == pytest.approx(0.2)
    assert stats["mean_delay_s"] >= 0.2 - 1e-6
    assert stats["points_marked"] > 0  # people mapped before their mask came back
    kp = a.keypoints
    assert kp["dropped"]["semantic"] > 0  # by the carried masks
    assert kp["extracted"] - kp["kept"] == sum(kp["dropped"].values())
    assert a.segmentation_thread == "semantic" and a.tracked_fraction == 1.0
    # A longer latency: fewer masks.
    assert _thread_run(path, 0.6).segmented_frames < a.segmented_frames


def test_the_map_starts_from_a_masked_frame(synthetic_sequence) -> None:
    # No mask of the thread comes back within the run: only the first keyframe's, waited for,
    # filters (its frame, and carried, the frames after it).
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    result = _thread_run(path, 100.0)
    assert result.semantic_thread is not None
    assert result.semantic_thread["delivered"] == 0 and result.segmented_frames == 1
    assert result.semantic_thread["first_wait_s"] == pytest.approx(100.0)
    assert result.keypoints["dropped"]["semantic"] > 20 * 10  # on every frame, not the first only


def test_cli_thread_schedule_and_latency_errors(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path / "thread"
    base = ("sequence.max_frames=15", "segmenter=labels", "filters=[semantic]")
    cfg = slam_run_config(path, out, *base, "segment=thread", "segmenter.latency_s=0.1")
    run(cfg)
    seg = json.loads((out / "metrics.json").read_text())["segmentation"]
    assert seg["schedule"] == "thread" and seg["thread"] == "semantic"
    assert seg["semantic_thread"]["delivered"] >= 1
    assert "in a semantic thread off the tracking path" in (out / "report.md").read_text()
    bad = slam_run_config(path, tmp_path / "bad", *base, "segmenter.latency_s=-1")
    with pytest.raises(UssSlamError, match=r"segmenter\.latency_s"):
        check(bad)
    unsimulated = slam_run_config(path, tmp_path / "u", *base, "segmenter.latency_s=0.5")
    with pytest.raises(UssSlamError, match=r"segmenter\.latency_s=0\.5 is simulated by segment="):
        check(unsimulated)
    waits = slam_run_config(
        path, tmp_path / "w", *base, "segmenter.latency_s=0.5", "segmenter.wait=true"
    )
    check(waits)  # really waiting is allowed on any schedule
    with pytest.raises(UssSlamError, match="segmenter.latency_s: expected a number >= 0"):
        LabelsSegmenter(latency_s=-0.1)
    seq = TumSequence(path, load_labels=True)
    with pytest.raises(UssSlamError, match="simulated by segment=thread only"):
        SlamPipeline(seq, LabelsSegmenter(latency_s=0.5), [], segment="keyframes")


def test_the_wall_thread_can_run_nicer_than_tracking() -> None:
    seen: list[int] = []

    class Nice:
        name, needs_labels = "nice", False

        def segment(self, frame):  # noqa: ANN001, ANN202
            seen.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
            return None

    own = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    thread = start_thread(Nice(), nice=3)
    assert isinstance(thread, WallThread)
    thread.request(_frame(0, 0.0), kf_id=0)
    deadline = time.perf_counter() + 5.0
    while not seen and time.perf_counter() < deadline:
        time.sleep(0.01)
    thread.close()
    assert seen == [min(own + 3, 19)]
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == own  # the caller's


def test_a_segmentation_under_way_is_finished_before_the_interpreter_exits(tmp_path) -> None:
    """A run's thread abandoned mid-segmentation: the exit waits for it (a native segmenter
    still computing while the interpreter tears down would abort the process)."""
    import subprocess
    import sys

    done = tmp_path / "done"
    script = f"""
import time, numpy as np
from types import SimpleNamespace
from uss_slam.slam_eval.systems.semantic_thread import start_thread

class Slow:
    name, needs_labels = "slow", False
    def segment(self, frame):
        time.sleep(0.5)
        open({str(done)!r}, "w").write("finished")
        return None

thread = start_thread(Slow())
thread.request(SimpleNamespace(stamp=0.0), kf_id=0)
time.sleep(0.1)
thread.close()  # returns at once, the segmentation still under way
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert done.read_text() == "finished"

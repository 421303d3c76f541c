"""``slam.mask_refits_keyframes`` and ``slam.final_ba``: a late mask carried back to the
keyframes made since the previous mask erases their observations inside it (not where a keyframe
would keep fewer than ``slam.mask_refit_min_observations``), and the end-of-run bundle
adjustment of the whole map."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.systems.late_mask import (
    erase_carried,
    final_ba_runs,
    since_previous,
)
from uss_slam.slam_eval.systems.semantic_thread import CarriedMask

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


class _Map:
    """The parts of a map :func:`erase_carried` uses: keyframes at ``poses`` (camera-to-world),
    each with the keypoints ``xy`` and the map point each observes, and the erasures asked."""

    def __init__(
        self, poses: list[np.ndarray], xy: np.ndarray, point_ids: list[list[int]], n_points=20
    ):
        self.keyframes = [
            SimpleNamespace(
                id=i,
                bad=False,
                features=SimpleNamespace(xy=xy),
                point_ids=np.array(ids, np.int64),
                dynamic=np.zeros(len(xy), bool),
            )
            for i, ids in enumerate(point_ids)
        ]
        self.poses = poses
        self.points = SimpleNamespace(bad=SimpleNamespace(view=np.zeros(n_points, bool)))
        self.erased: list[tuple[int, int]] = []

    def pose_wc(self, kf_id: int) -> np.ndarray:
        return self.poses[kf_id]

    def erase_observations(self, point_ids: np.ndarray, keyframe_ids: np.ndarray) -> int:
        self.erased += list(zip(point_ids.tolist(), keyframe_ids.tolist(), strict=True))
        return len(point_ids)


def test_the_carried_mask_erases_the_keyframes_observations_inside_it() -> None:
    labels = np.zeros((480, 640), np.uint8)
    labels[200:280, 280:360] = 1  # a person ahead of keyframe 0, 2 m away
    depth = np.full(labels.shape, 2.0, np.float32)
    carried = CarriedMask.of(0, labels, depth, K)
    shifted = np.eye(4)
    shifted[0, 3] = 0.4  # keyframe 2 stands 0.4 m to the right: the person 100 px to the left
    xy = np.array([[320.0, 240.0], [220.0, 240.0], [600.0, 50.0]])
    slam_map = _Map([np.eye(4), np.eye(4), shifted], xy, [[5, 6, 7], [8, -1, 9], [10, 11, 12]])
    erased, kept = erase_carried(slam_map, carried, [1, 2], lambda lab: lab > 0)
    # keyframe 1 sees the person at the centre (its keypoint 1 observes nothing), keyframe 2
    # 100 px to the left; the keypoint in the corner is outside the person in both
    assert erased == 2 and kept == [1, 2]
    assert slam_map.erased == [(8, 1), (11, 2)]
    np.testing.assert_array_equal(slam_map.keyframes[1].dynamic, [True, False, False])
    np.testing.assert_array_equal(slam_map.keyframes[2].dynamic, [False, True, False])
    assert erase_carried(slam_map, carried, [1], lambda lab: None) == (0, [1])  # no region


def _person_ahead() -> CarriedMask:
    labels = np.zeros((480, 640), np.uint8)
    labels[200:280, 280:360] = 1
    return CarriedMask.of(0, labels, np.full(labels.shape, 2.0, np.float32), K)


def test_a_keyframe_left_under_the_floor_is_not_refit() -> None:
    """The floor counts the good map points a keyframe would still observe outside the mask."""
    xy = np.array([[320.0, 240.0], [600.0, 50.0], [50.0, 50.0], [600.0, 400.0]])
    slam_map = _Map([np.eye(4)] * 3, xy, [[5, 6, 7, 8], [9, 10, 11, -1], [12, 13, 14, 15]])
    slam_map.points.bad.view[15] = True  # keyframe 2 keeps 2 good points outside, keyframe 1 2
    erased, kept = erase_carried(slam_map, _person_ahead(), [1, 2], lambda lab: lab > 0, 3)
    assert (erased, kept, slam_map.erased) == (0, [], [])
    assert not slam_map.keyframes[1].dynamic.any() and not slam_map.keyframes[2].dynamic.any()
    slam_map.points.bad.view[15] = False  # keyframe 2 now keeps 3: refit, keyframe 1 not
    erased, kept = erase_carried(slam_map, _person_ahead(), [1, 2], lambda lab: lab > 0, 3)
    assert (erased, kept, slam_map.erased) == (1, [2], [(12, 2)])
    np.testing.assert_array_equal(slam_map.keyframes[2].dynamic, [True, False, False, False])
    # no region: nothing to erase, the keyframe stays free whatever the floor
    assert erase_carried(slam_map, _person_ahead(), [1], lambda lab: None, 99) == (0, [1])


def test_since_previous_takes_the_good_keyframes_after_the_previous_mask() -> None:
    slam_map = _Map([np.eye(4)] * 6, np.zeros((1, 2)), [[-1]] * 6)
    slam_map.keyframes[3].bad = True
    assert since_previous(slam_map, 4, 1) == [2, 5]
    assert since_previous(slam_map, 4, None) == []


def test_final_ba_runs_with_the_schedules_it_names() -> None:
    assert final_ba_runs("thread", "thread") and not final_ba_runs("thread", "every_frame")
    assert final_ba_runs("always", "keyframes") and not final_ba_runs("none", "thread")
    with pytest.raises(ValueError, match="final_ba"):
        final_ba_runs("yes", "thread")


def _run(path: Path, segment: str = "thread", **keys: object):
    seq = TumSequence(path, load_labels=True)
    latency = 0.3 if segment == "thread" else 0.0
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=latency), build_filters(["semantic"]),
        segment=segment, progress=False, local_ba=True, **keys,
    ).run()  # fmt: skip


def test_refit_keyframes_end_to_end(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    off, on = _run(path), _run(path, mask_refits_keyframes=True)
    again = _run(path, mask_refits_keyframes=True)
    assert off.semantic_thread is not None and on.semantic_thread is not None
    assert "observations_erased_carried" not in off.semantic_thread
    assert on.semantic_thread["observations_erased_carried"] > 0
    np.testing.assert_array_equal(on.trajectory.positions, again.trajectory.positions)
    assert not np.array_equal(on.trajectory.positions, off.trajectory.positions)
    assert on.semantic_thread["keyframes_refit_skipped"] == 0  # no floor: every keyframe refit
    # a floor no keyframe reaches: nothing erased, no keyframe freed, today's trajectory
    none = _run(path, mask_refits_keyframes=True, mask_refit_min_observations=10**6)
    assert none.semantic_thread is not None
    assert none.semantic_thread["observations_erased_carried"] == 0
    assert none.semantic_thread["keyframes_refit_skipped"] > 0
    np.testing.assert_array_equal(none.trajectory.positions, off.trajectory.positions)


def test_final_ba_end_to_end(synthetic_sequence) -> None:
    """The thread's masks in flight at the end are delivered, the whole map adjusted; the
    frames' rate leaves the end-of-run pass out."""
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    off, on = _run(path), _run(path, final_ba="thread")
    assert off.semantic_thread is not None and on.semantic_thread is not None
    assert on.semantic_thread["delivered"] >= off.semantic_thread["delivered"]
    assert (
        on.semantic_thread["requested"]
        == on.semantic_thread["delivered"] + on.semantic_thread["skipped"]
    )
    assert "final_ba" in on.timing_ms and "final_ba" not in off.timing_ms
    assert not np.array_equal(on.trajectory.positions, off.trajectory.positions)
    np.testing.assert_array_equal(on.trajectory.stamps, off.trajectory.stamps)
    per_frame = _run(path, "every_frame", final_ba="thread")
    assert "final_ba" not in per_frame.timing_ms  # `thread`: the other schedules skip it
    assert "final_ba" in _run(path, "every_frame", final_ba="always").timing_ms


def test_defaults_leave_both_off(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    slam = slam_run_config(path, tmp_path / "a", "segmenter=labels", "filters=[semantic]").slam
    assert (slam.mask_refits_keyframes, slam.final_ba) == (False, "none")
    assert slam.mask_refit_min_observations == 0


def test_the_end_of_run_adjustment_keeps_its_own_iterations(monkeypatch) -> None:
    """The end-of-run bundle adjustment runs ORB-SLAM3's 10 iterations whatever local BA's
    ``first_iterations`` (2 by default)."""
    from contextlib import nullcontext

    from uss_slam.slam_eval.mapping.local_mapping import LocalMappingConfig
    from uss_slam.slam_eval.systems import frame_loop, late_mask

    calls = []
    adjuster = SimpleNamespace(
        adjust=lambda *args: calls.append(args[3:]) or SimpleNamespace(outliers=0)
    )
    kfs = [SimpleNamespace(id=0, bad=False), SimpleNamespace(id=1, bad=True)]
    slam_map = SimpleNamespace(keyframes=kfs, points_of=lambda free: free)
    loop = SimpleNamespace(
        final_ba=True,
        mapper=SimpleNamespace(adjuster=adjuster, config=LocalMappingConfig()),
        semantic=None,
        map=slam_map,
        timer=lambda name: nullcontext(),
        counts={"final_ba_outliers": 0},
    )
    monkeypatch.setattr(frame_loop, "adjust_all", late_mask.adjust_all)
    frame_loop.FrameLoop.finish(loop)
    assert calls == [(10, 0)] and LocalMappingConfig().first_iterations == 2

"""``slam.carry_to_keyframes``: a delivered keyframe mask of the semantic thread also carried to
the keyframes that got none (their poses, the mask's depth), marking the points they see on it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.config import check
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.systems.semantic_thread import CarriedMask, carry_targets, mark_carried

PERSON = CLASS_NAMES.index("person")
K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _map(poses: list[np.ndarray], bad: tuple[int, ...] = (), xy=None, point_ids=None):
    """A stand-in map: keyframes with ``poses`` (camera-to-world), each observing the points
    ``point_ids`` through keypoints at ``xy`` (pixels)."""
    xy = np.zeros((0, 2)) if xy is None else xy
    ids = np.zeros(0, np.int64) if point_ids is None else point_ids
    keyframes = [
        SimpleNamespace(
            id=i, bad=i in bad, features=SimpleNamespace(xy=xy), point_ids=ids.copy(),
            dynamic=np.zeros(len(xy), bool),
        )
        for i in range(len(poses))
    ]  # fmt: skip
    n = int(ids.max()) + 1 if len(ids) else 0
    points = SimpleNamespace(bad=SimpleNamespace(view=np.zeros(n, bool)))
    return SimpleNamespace(keyframes=keyframes, points=points, pose_wc=lambda i: poses[i])


def test_carry_targets_per_reach() -> None:
    slam_map = _map([np.eye(4)] * 7, bad=(4,))
    assert carry_targets(slam_map, 2, 0, "none") == []
    assert carry_targets(slam_map, 2, 0, "newer") == [3, 5, 6]  # keyframe 4 was culled
    assert carry_targets(slam_map, 2, 0, "since_previous") == [1, 3, 5, 6]
    assert carry_targets(slam_map, 2, None, "since_previous") == [0, 1, 3, 5, 6]
    assert carry_targets(slam_map, 6, 2, "newer") == []
    with pytest.raises(ValueError, match="carry_to_keyframes"):
        carry_targets(slam_map, 2, 0, "older")


def test_a_carried_mask_marks_the_points_a_later_keyframe_sees_on_the_person() -> None:
    # The person: a 0.4 m square on the plane z = 2 m, centred on the keyframe's optical axis
    # (pixels 270..370 x 190..290). The later keyframe is 0.5 m to the right (x), so it sees the
    # square 125 px further left: around (195, 240), where the mask's own keyframe sees
    # background; its keypoint at (320, 240) now sees background.
    labels = np.zeros((480, 640), np.uint8)
    labels[190:291, 270:371] = PERSON
    depth = np.full(labels.shape, 2.0, np.float32)
    carried = CarriedMask.of(0, labels, depth, K)
    right = np.eye(4)
    right[0, 3] = 0.5
    xy = np.array([[195.0, 240.0], [320.0, 240.0], [600.0, 50.0]])
    slam_map = _map([np.eye(4), right], xy=xy, point_ids=np.array([0, 1, 2]))
    marked = mark_carried(slam_map, carried, [1], lambda lab: lab == PERSON)
    assert marked == 1
    np.testing.assert_array_equal(slam_map.points.bad.view, [True, False, False])
    np.testing.assert_array_equal(slam_map.keyframes[1].dynamic, [True, False, False])
    assert not slam_map.keyframes[0].dynamic.any()  # only the targets are touched
    assert mark_carried(slam_map, carried, [1], lambda lab: lab == PERSON) == 0  # already bad


def _run(path: Path, reach: str):
    seq = TumSequence(path, load_labels=True)
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=0.3), build_filters(["semantic"]),
        segment="thread", progress=False, carry_to_keyframes=reach,
    ).run()  # fmt: skip


def test_carry_to_keyframes_end_to_end(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    none, newer, since = _run(path, "none"), _run(path, "newer"), _run(path, "since_previous")
    assert none.semantic_thread is not None and "keyframes_carried" not in none.semantic_thread
    a, b = newer.semantic_thread, since.semantic_thread
    assert a is not None and b is not None
    assert a["keyframes_carried"] > 0 and a["points_marked_carried"] > 0
    assert b["keyframes_carried"] >= a["keyframes_carried"]
    again = _run(path, "newer")
    np.testing.assert_array_equal(newer.trajectory.positions, again.trajectory.positions)


def test_an_unknown_reach_is_one_line(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    cfg = slam_run_config(path, tmp_path, "segment=thread", "slam.carry_to_keyframes=older")
    with pytest.raises(UssSlamError, match="carry_to_keyframes"):
        check(cfg)


def test_carrying_needs_the_thread(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    base = ("segmenter=labels", "filters=[semantic]", "slam.carry_to_keyframes=newer")
    with pytest.raises(UssSlamError, match=r"carry_to_keyframes=newer needs segment=thread"):
        check(slam_run_config(path, tmp_path / "a", *base))
    check(slam_run_config(path, tmp_path / "b", *base, "segment=thread"))

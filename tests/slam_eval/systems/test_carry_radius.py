"""``slam.carry_radius_m``: a keypoint whose 3D point lies near the semantic thread's carried
people is flagged with them."""

from __future__ import annotations

from pathlib import Path

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
from uss_slam.slam_eval.systems.semantic_thread import CarriedMask, classes_near

PERSON = CLASS_NAMES.index("person")
K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def test_only_keypoints_near_the_people_in_3d_take_their_class() -> None:
    labels = np.zeros((480, 640), np.uint8)
    labels[190:290, 270:370] = PERSON  # a 0.2 m square person 1 m ahead, on the optical axis
    carried = CarriedMask.of(0, labels, np.full(labels.shape, 1.0, np.float32), K)
    ahead = np.eye(4)
    ahead[2, 3] = 0.5  # the frame's camera 0.5 m behind the keyframe's: the person 1.5 m ahead
    points = np.array([
        [0.25, 0.0, 1.5],  # 0.15 m right of the person's edge, at its depth: a step away
        [0.25, 0.0, 3.0],  # the same pixel ray, the wall 1.5 m behind: not near
        [0.0, 0.0, 1.25],  # 0.25 m in front of the person's centre
        [np.nan, np.nan, np.nan],  # no depth
    ])  # fmt: skip
    cls = classes_near(carried, ahead, points, 0.3)
    np.testing.assert_array_equal(cls, [PERSON, 0, PERSON, 0])
    assert not classes_near(carried, ahead, points, 0.1)[0]


def test_the_class_of_the_nearest_carried_point_as_a_brute_force_search_finds_it() -> None:
    """The tree built for each frame finds what comparing every pair finds: the class of the
    nearest carried point within the radius (several classes, points of several depths)."""
    rng = np.random.default_rng(3)
    labels = rng.integers(0, 4, (120, 160)).astype(np.uint8)
    depth = rng.uniform(0.5, 3.0, labels.shape).astype(np.float32)
    carried = CarriedMask.of(0, labels, depth, K)
    moved = np.eye(4)
    moved[:3, 3] = [0.05, -0.02, 0.1]
    points = rng.uniform([-0.3, -0.3, 0.5], [0.3, 0.3, 3.0], (500, 3))
    points[::7] = np.nan  # keypoints without depth
    in_frame = carried.points @ moved[:3, :3].T + moved[:3, 3]
    for radius in (0.02, 0.05, 0.3):
        expected = np.zeros(len(points), np.uint8)
        for i, point in enumerate(points):
            if np.isfinite(point).all():
                dist = np.linalg.norm(in_frame - point, axis=1)
                nearest = int(np.argmin(dist))
                expected[i] = carried.classes[nearest] if dist[nearest] <= radius else 0
        np.testing.assert_array_equal(classes_near(carried, moved, points, radius), expected)


def _run(path: Path, radius: float | None, keypoints: str = "all", floor: int = 0):
    """A thread run; the floor 0 unless given (the radius on every frame)."""
    seq = TumSequence(path, load_labels=True)
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=0.3), build_filters(["semantic"]),
        segment="thread", progress=False, carry_radius_m=radius,
        carry_radius_keypoints=keypoints, carry_radius_min_inliers=floor,
    ).run()  # fmt: skip


def test_carry_radius_end_to_end(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    off, on, again = _run(path, None), _run(path, 0.3), _run(path, 0.3)
    assert off.semantic_thread is not None and "keypoints_near_people" not in off.semantic_thread
    assert on.semantic_thread is not None and on.semantic_thread["keypoints_near_people"] > 0
    np.testing.assert_array_equal(on.trajectory.positions, again.trajectory.positions)
    assert on.keypoints["dropped"]["semantic"] > off.keypoints["dropped"]["semantic"]
    untracked = _run(path, 0.3, "untracked").semantic_thread
    assert untracked is not None
    assert 0 < untracked["keypoints_near_people"] < on.semantic_thread["keypoints_near_people"]
    assert "frames_radius_skipped" not in on.semantic_thread
    never = _run(path, 0.3, floor=100_000).semantic_thread  # no frame has that many inliers
    assert never is not None and "keypoints_near_people" not in never
    assert never["frames_radius_skipped"] > 30


def test_carry_radius_defaults_and_bounds(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    base = ("segmenter=labels", "filters=[semantic]")
    slam = slam_run_config(path, tmp_path / "a", *base).slam
    assert (slam.carry_radius_m, slam.carry_radius_min_inliers) == (0.3, 100)
    check(slam_run_config(path, tmp_path / "b", *base))  # other schedules ignore it
    check(slam_run_config(path, tmp_path / "c", *base, "slam.carry_radius_m=null"))
    with pytest.raises(UssSlamError, match="carry_radius_m"):
        check(slam_run_config(path, tmp_path / "d", *base, "slam.carry_radius_m=0"))
    with pytest.raises(UssSlamError, match="carry_radius_keypoints"):
        check(slam_run_config(path, tmp_path / "e", *base, "slam.carry_radius_keypoints=some"))

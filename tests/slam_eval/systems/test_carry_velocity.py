"""``slam.carry_velocity``: the semantic thread's carried mask also drawn where each person
moves to, at the velocity of its centroid between the last two delivered masks."""

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
from uss_slam.slam_eval.systems.semantic_thread import CarriedMask, people_motion

PERSON = CLASS_NAMES.index("person")
K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _person(left: int, stamp: float, depth_m: float = 2.0) -> CarriedMask:
    """A 100 px square person from column ``left``, ``depth_m`` ahead, and a small blob (too
    small to count as a person) in a corner."""
    labels = np.zeros((480, 640), np.uint8)
    labels[190:290, left : left + 100] = PERSON
    labels[0:12, 0:12] = PERSON
    depth = np.full(labels.shape, depth_m, np.float32)
    return CarriedMask.of(0, labels, depth, K, stamp)


def test_a_person_moves_at_its_centroids_velocity() -> None:
    before, now = _person(200, 0.0), _person(250, 0.5)  # 50 px at 2 m = 0.2 m in 0.5 s
    previous = people_motion(before, np.eye(4), None)
    assert len(previous[0]) == 1  # the corner blob is no person
    assert before.velocity is not None and not before.velocity.any()  # nothing to compare
    people_motion(now, np.eye(4), previous)
    assert now.velocity is not None
    moving = np.any(now.velocity != 0, axis=1)
    np.testing.assert_allclose(now.velocity[moving], [[0.4, 0.0, 0.0]] * moving.sum(), atol=0.02)
    assert moving.sum() == 25 * 25  # the square's grid points, not the corner's
    later = now.labels_at(np.eye(4), 0.5) == PERSON  # 0.2 m: 50 px on
    assert later[240, 260] and later[240, 390]  # where it was and where it goes (the union)
    assert not later[240, 420] and not (now.labels_at(np.eye(4)) == PERSON)[240, 380]
    capped = now.labels_at(np.eye(4), 5.0) == PERSON  # at most 1 s: 0.4 m = 100 px on
    assert capped[240, 440] and not capped[240, 460]


def test_a_region_too_far_from_any_earlier_one_stands_still() -> None:
    before, now = _person(0, 0.0, 1.0), _person(500, 0.2, 1.0)  # 1 m in 0.2 s: not the same
    people_motion(now, np.eye(4), people_motion(before, np.eye(4), None))
    assert now.velocity is not None and not now.velocity.any()


def _run(path: Path, velocity: bool):
    seq = TumSequence(path, load_labels=True)
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=0.3), build_filters(["semantic"]),
        segment="thread", progress=False, carry_velocity=velocity,
    ).run()  # fmt: skip


def test_carry_velocity_end_to_end(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    off, on, again = _run(path, False), _run(path, True), _run(path, True)
    assert off.semantic_thread is not None and "people_moving" not in off.semantic_thread
    assert on.semantic_thread is not None and on.semantic_thread["people_moving"] > 0
    np.testing.assert_array_equal(on.trajectory.positions, again.trajectory.positions)
    assert on.keypoints["dropped"]["semantic"] > off.keypoints["dropped"]["semantic"]


def test_carry_velocity_needs_the_thread(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    base = ("segmenter=labels", "filters=[semantic]", "slam.carry_velocity=true")
    with pytest.raises(UssSlamError, match=r"slam\.carry_velocity=true needs segment=thread"):
        check(slam_run_config(path, tmp_path / "a", *base))
    check(slam_run_config(path, tmp_path / "b", *base, "segment=thread"))

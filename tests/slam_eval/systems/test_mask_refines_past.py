"""``slam.mask_refines_past``: a late mask that marks map points bad also corrects the past
they steered (local BA around its keyframe again, the frames tracked on them refined)."""

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
from uss_slam.slam_eval.systems.mask_points import mark_projected

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _fake_map(positions: list[list[float]], first: list[int]) -> SimpleNamespace:
    """The parts of a map :func:`mark_projected` reads: good points, where and by which
    keyframe first mapped; keyframe 0 at the origin, looking down +z."""
    view = SimpleNamespace
    points = view(
        position=view(view=np.array(positions, float)),
        first_keyframe=view(view=np.array(first, np.int32)),
        bad=view(view=np.zeros(len(first), bool)),
    )
    return view(points=points, pose_wc=lambda kf_id: np.eye(4))


def test_projected_points_on_or_before_the_people_are_marked() -> None:
    region = np.zeros((480, 640), bool)
    region[190:290, 270:370] = True  # a person around the image centre
    depth = np.full(region.shape, 3.0, np.float32)
    depth[190:290, 270:370] = 1.5  # 1.5 m ahead, the wall 3 m behind
    depth[190:200, 270:280] = 0.0  # a hole in the person's depth
    slam_map = _fake_map(
        [
            [0.0, 0.0, 1.5],  # on the person: marked
            [0.0, 0.0, 1.0],  # in front of the person: marked
            [0.0, 0.0, 3.0],  # the wall the person hides: stays
            [1.0, 0.0, 3.0],  # the wall beside the person: stays
            [0.0, 0.0, 1.5],  # on the person, but mapped before the previous mask: stays
            [-0.145, -0.145, 1.5],  # in the hole (no depth): marked
            [0.0, 0.0, -1.5],  # behind the camera: stays
        ],
        [5, 5, 5, 5, 2, 5, 5],
    )
    assert mark_projected(slam_map, 7, region, depth, K, since=3) == 3
    np.testing.assert_array_equal(
        slam_map.points.bad.view, [True, True, False, False, False, True, False]
    )
    assert mark_projected(slam_map, 7, region, depth, K, since=3) == 0  # bad ones stay out


def _run(path: Path, refine: str, segment: str = "thread", projected: bool = False):
    seq = TumSequence(path, load_labels=True)
    latency = 0.3 if segment == "thread" else 0.0
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=latency), build_filters(["semantic"]),
        segment=segment, progress=False, local_ba=True, mask_refines_past=refine,
        mask_marks_projected=projected,
    ).run()  # fmt: skip


def test_mask_refines_past_end_to_end(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    off, on, again = _run(path, "none"), _run(path, "points"), _run(path, "points")
    assert off.semantic_thread is not None and on.semantic_thread is not None
    assert "past_frames_refined" not in off.semantic_thread
    assert on.semantic_thread["past_frames_refined"] > 0
    assert off.local_ba is not None and on.local_ba is not None
    assert off.local_ba["readjusted"] == 0 < on.local_ba["readjusted"]
    assert on.local_ba["readjusted"] <= on.semantic_thread["delivered"]
    np.testing.assert_array_equal(on.trajectory.positions, again.trajectory.positions)
    assert not np.array_equal(on.trajectory.positions, off.trajectory.positions)


@pytest.mark.parametrize("segment", ["every_frame", "keyframes"])
def test_other_schedules_ignore_it(synthetic_sequence, segment: str) -> None:
    """Masks on every frame or on keyframes in the main thread are never late: the keys
    change no trajectory there."""
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    off = _run(path, "none", segment)
    on = _run(path, "mask", segment, projected=True)
    np.testing.assert_array_equal(on.trajectory.positions, off.trajectory.positions)
    np.testing.assert_array_equal(on.trajectory.quaternions, off.trajectory.quaternions)
    assert on.local_ba is not None and on.local_ba["readjusted"] == 0


def test_mask_refines_past_defaults(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    slam = slam_run_config(path, tmp_path / "a", "segmenter=labels", "filters=[semantic]").slam
    assert (slam.mask_refines_past, slam.mask_marks_projected) == ("mask", False)

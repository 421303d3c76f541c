"""``slam.mask_refines_past``: a late mask that marks map points bad also corrects the past
they steered (local BA around its keyframe again, the frames tracked on them refined)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from shared_helpers import slam_run_config

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline


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


def test_other_schedules_ignore_it(synthetic_sequence) -> None:
    """Masks on every frame are never late: the key changes no trajectory there."""
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    off = _run(path, "none", "every_frame")
    on = _run(path, "mask", "every_frame", projected=True)
    np.testing.assert_array_equal(on.trajectory.positions, off.trajectory.positions)
    np.testing.assert_array_equal(on.trajectory.quaternions, off.trajectory.quaternions)
    assert on.local_ba is not None and on.local_ba["readjusted"] == 0


def test_mask_refines_past_is_off_by_default(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    slam = slam_run_config(path, tmp_path / "a", "segmenter=labels", "filters=[semantic]").slam
    assert (slam.mask_refines_past, slam.mask_marks_projected) == ("none", False)

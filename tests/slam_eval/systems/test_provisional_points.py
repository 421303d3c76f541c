"""``slam.provisional_points`` (an experiment of the semantic thread, off by default): a keyframe
made without a mask holds its new map points back until a mask judges them, and while the newest
keyframe's held points all wait, the next keyframe waits ``max_keyframe_interval`` frames."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.config import check
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.frame_loop import FrameLoop
from uss_slam.slam_eval.systems.harness import SlamPipeline


def _loop(since: int, wants: bool) -> FrameLoop:
    tracker = SimpleNamespace(
        frames_since_keyframe=since,
        config=SimpleNamespace(max_keyframe_interval=30),
        wants_keyframe=lambda result, features, dynamic: wants,
    )
    none = None
    return FrameLoop(none, tracker, none, none, none, none, none, none, provisional_points=True)


def test_keyframe_gate_holds_the_next_keyframe_while_the_newest_waits() -> None:
    filters = SimpleNamespace(ctx=SimpleNamespace(features=None), dynamic=None)
    loop = _loop(since=3, wants=True)
    assert loop.keyframe_gate(filters, None) is None  # nothing held: the tracker decides
    loop.pending = np.array([4, 5, 6])
    loop.provisional = np.array([1, 4, 5, 6, 9])
    assert loop.keyframe_gate(filters, None) is False  # every held point still waits
    assert loop.counts["keyframes_gated"] == 1
    loop.tracker.frames_since_keyframe = 29  # the 30th frame since the last keyframe
    assert loop.keyframe_gate(filters, None) is None
    loop.tracker.frames_since_keyframe = 3
    loop.provisional = np.array([1, 4, 6, 9])  # a mask judged point 5
    assert loop.keyframe_gate(filters, None) is None


def _run(path: Path, provisional: bool, border: int | None = None):
    seq = TumSequence(path, load_labels=True)
    return SlamPipeline(
        seq, LabelsSegmenter(latency_s=0.2), build_filters(["semantic"]),
        segment="thread", progress=False, provisional_points=provisional,
        provisional_border_px=border,
    ).run()  # fmt: skip


def test_provisional_points_end_to_end(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    off, on, again = _run(path, False), _run(path, True), _run(path, True)
    assert off.semantic_thread is not None and "points_held" not in off.semantic_thread
    stats = on.semantic_thread
    assert stats is not None and stats["points_held"] > 0
    assert stats["points_cleared"] + stats["points_dropped"] > 0  # masks judged some
    assert stats["points_cleared"] + stats["points_dropped"] <= stats["points_held"]
    np.testing.assert_array_equal(on.trajectory.positions, again.trajectory.positions)
    assert on.keyframes <= off.keyframes + 1  # the gate: no keyframe cascade


def test_a_border_holds_only_the_points_near_the_carried_mask(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    every, near, none = _run(path, True, 10_000), _run(path, True, 40), _run(path, True, 0)
    stats = [r.semantic_thread for r in (every, near, none)]
    assert all(s is not None for s in stats)
    held = [s["points_held"] for s in stats]
    assert held[0] > held[1] > held[2]  # 0 px: only what the filter's own dilation covers
    assert "keyframes_gated" not in near.semantic_thread  # no keyframe gate with a border


def test_provisional_points_need_the_thread(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=20)
    base = ("segmenter=labels", "filters=[semantic]", "slam.provisional_points=true")
    with pytest.raises(UssSlamError, match=r"slam\.provisional_points=true needs segment=thread"):
        check(slam_run_config(path, tmp_path / "a", *base))
    check(slam_run_config(path, tmp_path / "b", *base, "segment=thread"))
    seq = TumSequence(path, load_labels=True)
    with pytest.raises(UssSlamError, match="needs segment=thread"):
        SlamPipeline(seq, LabelsSegmenter(), [], segment="keyframes", provisional_points=True)

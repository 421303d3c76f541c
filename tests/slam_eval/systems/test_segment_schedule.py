"""Segmentation schedule of the pipeline: every frame (prefetch threads, concurrently with ORB
extraction) or keyframes only (main thread, before the keyframe's map points exist)."""

from __future__ import annotations

import hashlib
import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.segmenters.base import ImageSegmenter, LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import RunResult, SlamPipeline

PERSON = CLASS_NAMES.index("person")


def _key(rgb: np.ndarray) -> bytes:
    return hashlib.sha1(np.ascontiguousarray(rgb).tobytes()).digest()


class SlowOracle(ImageSegmenter):
    """An image segmenter that takes ``delay`` seconds per image and answers with the sequence's
    ground-truth labels (found by the image's content: it sees only the RGB image). Records
    ``(frame index, thread name, start, end)`` of every call."""

    name = "slow-oracle"

    def __init__(self, path: Path, delay: float = 0.03) -> None:
        seq = TumSequence(path, load_labels=True)
        self.answers = {}
        for i in range(len(seq)):
            frame = seq.load(i)
            self.answers[_key(frame.rgb)] = (i, frame.labels)
        self.delay = delay
        self.calls: list[tuple[int, str, float, float]] = []
        self._lock = threading.Lock()

    def infer(self, rgb: np.ndarray) -> np.ndarray:
        start = time.perf_counter()
        time.sleep(self.delay)
        index, labels = self.answers[_key(rgb)]
        with self._lock:
            self.calls.append((index, threading.current_thread().name, start, time.perf_counter()))
        return labels


def _run(path: Path, segmenter, segment: str, filters=("semantic",)) -> RunResult:
    seq = TumSequence(path, load_labels=segmenter.needs_labels)
    return SlamPipeline(
        seq, segmenter, build_filters(list(filters)), segment=segment, progress=False
    ).run()


def _same_run(a: RunResult, b: RunResult) -> None:
    np.testing.assert_array_equal(a.trajectory.stamps, b.trajectory.stamps)
    np.testing.assert_array_equal(a.trajectory.positions, b.trajectory.positions)
    assert a.keypoints == b.keypoints
    assert [e.keyframe for e in a.log] == [e.keyframe for e in b.log]


def test_every_frame_segments_in_the_prefetch_threads_concurrently(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    slow = SlowOracle(path, delay=0.03)
    result = _run(path, slow, "every_frame")
    assert sorted(c[0] for c in slow.calls) == list(range(30))  # each frame once
    assert all(c[1].startswith("tum-prefetch") for c in slow.calls)
    calls = sorted(slow.calls, key=lambda c: c[2])
    # Two workers: some call starts before the previous one ended.
    assert any(b[2] < a[3] for a, b in zip(calls, calls[1:], strict=False))
    assert result.segment == "every_frame" and result.segmentation_thread == "prefetch"
    assert result.segmented_frames == 30
    assert result.segmentation_ms["wall"] >= 30.0  # the sleep, per segmented frame
    assert result.timing_ms["segmentation"] == pytest.approx(result.segmentation_ms["wall"])
    # Same labels as the oracle: the same run, whichever thread produced them.
    _same_run(result, _run(path, LabelsSegmenter(), "every_frame"))


def test_keyframes_schedule_segments_keyframes_only(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    slow = SlowOracle(path, delay=0.01)
    result = _run(path, slow, "keyframes")
    keyframes = [e.index for e in result.log if e.keyframe]
    assert keyframes[0] == 0 and len(keyframes) == result.keyframes >= 2
    assert [c[0] for c in slow.calls] == keyframes  # in order, nothing else
    assert {c[1] for c in slow.calls} == {threading.main_thread().name}
    assert result.segment == "keyframes" and result.segmentation_thread == "main"
    assert result.segmented_frames == len(keyframes)
    assert result.segmentation_ms["wall"] >= 10.0
    assert result.timing_ms["segmentation"] == pytest.approx(
        result.segmentation_ms["wall"] * len(keyframes) / result.frames
    )
    kp = result.keypoints
    # The semantic filter judged the keyframes' keypoints and nothing else.
    assert kp["checked"]["semantic"] == sum(e.keypoints for e in result.log if e.keyframe)
    assert kp["dropped"]["semantic"] > 0
    assert all(e.kept == e.keypoints for e in result.log if not e.keyframe)
    assert PERSON not in set(result.cloud.labels.tolist())  # keyframes were filtered
    assert result.tracked_fraction == 1.0
    _same_run(result, _run(path, LabelsSegmenter(), "keyframes"))


def test_keyframes_schedule_keeps_motion_filters_on_every_frame(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    result = _run(path, LabelsSegmenter(), "keyframes", ("semantic", "geometry", "object"))
    kp = result.keypoints
    keyframe_keypoints = sum(e.keypoints for e in result.log if e.keyframe)
    assert kp["checked"]["semantic"] == keyframe_keypoints
    assert kp["checked"]["geometry"] > keyframe_keypoints  # judged on ordinary frames too
    assert kp["extracted"] - kp["kept"] == sum(kp["dropped"].values())


def test_unknown_schedule_and_bad_labels_are_clear(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    seq = TumSequence(path, load_labels=True)
    with pytest.raises(UssSlamError, match="segment='sometimes': choose every_frame"):
        SlamPipeline(seq, LabelsSegmenter(), [], segment="sometimes")

    class Wrong(ImageSegmenter):
        name = "wrong"

        def infer(self, rgb: np.ndarray) -> np.ndarray:
            return np.zeros(rgb.shape[:2], np.int64)

    with pytest.raises(UssSlamError, match="segmenter 'wrong' returned labels .* int64"):
        Wrong().segment(seq.load(0))


def test_cli_segment_keyframes_reports_both_timings(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path / "kf"
    cfg = slam_run_config(
        path, out, "sequence.max_frames=15", "segmenter=labels", "filters=[semantic]",
        "segment=keyframes",
    )  # fmt: skip
    assert cfg.segment == "keyframes"
    data = run(cfg)
    metrics = json.loads((out / "metrics.json").read_text())
    seg = metrics["segmentation"]
    assert seg == data["segmentation"]
    assert seg["schedule"] == "keyframes" and seg["thread"] == "main"
    assert seg["frames_segmented"] == metrics["keyframes"] >= 1
    assert seg["wall_ms"] > 0 and seg["cpu_ms"] >= 0 and seg["orb_wall_ms"] > 0
    report = (out / "report.md").read_text()
    assert "Segmentation (labels, keyframes only, in the main thread)" in report

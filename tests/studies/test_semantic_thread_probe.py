"""``studies/semantic_thread_probe.py``: its counts against the frames' ground-truth labels."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from uss_slam.testing.scripts import load_script

probe = load_script(Path(__file__).resolve().parents[2] / "studies" / "semantic_thread_probe.py")


def _probe(monkeypatch, path: Path, out: Path, *sets: str) -> dict:
    argv = ["semantic_thread_probe.py", str(path), "--out", str(out), "--set", *sets]
    monkeypatch.setattr(sys, "argv", argv)
    rule, record = probe.tracker_module.need_keyframe, probe.FrameLoop.record
    probe.main()
    assert (probe.tracker_module.need_keyframe, probe.FrameLoop.record) == (rule, record)
    return json.loads(out.read_text())


def test_per_frame_masks_leave_no_person_in_and_the_thread_does(
    synthetic_sequence, tmp_path: Path, monkeypatch
) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=40)
    base = ("slam.local_ba=false", "slam.loop_closing=false")
    every = _probe(monkeypatch, path, tmp_path / "a.json", "segment=every_frame", *base)
    assert len(every["frames"]) == 40 and every["keyframes"] >= 2
    assert every["mean_person_inliers"] == 0 and every["created_on_person"] == 0
    assert every["created"] > 0 and sum(every["reasons"].values()) == every["keyframes"] - 1
    late = ("segment=thread", "segmenter.latency_s=100", *base)  # only the first mask comes
    thread = _probe(monkeypatch, path, tmp_path / "b.json", *late)
    assert thread["created_on_person"] > 0  # the people walked out of the first mask
    assert thread["semantic_thread"]["delivered"] == 0

"""``system=orbslam3 segment=thread``: the camera-clock schedule of the segmented frames, the mask
carried by ORB-SLAM3's previous tracked pose and blanked in its input, the bad inputs, and a tiny
real run (pyorbslam3, optional)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.sequence import Frame
from uss_slam.slam_eval.systems.orbslam3.masking import dynamic_mask
from uss_slam.slam_eval.systems.orbslam3.thread import Carrier, schedule
from uss_slam.slam_eval.systems.orbslam3.vocabulary import build_from_sequences

PERSON = CLASS_NAMES.index("person")
K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def test_one_segmentation_at_a_time_each_arriving_latency_s_after_its_frame() -> None:
    stamps = np.arange(100) / 30.0
    plan = schedule(stamps, 0.5)
    # frame 0 is waited for; frame 1 (stamp 1/30) is done at 16/30: frame 16 gets it and the
    # thread starts on frame 16 itself, and so on; the last one never arrives (100 = never)
    assert plan.segmented == (0, 1, 16, 31, 46, 61, 76, 91)
    assert plan.delivered == (0, 16, 31, 46, 61, 76, 91, 100)
    every = schedule(stamps[:5], 0.0)  # no latency: each frame's mask reaches the next frame
    assert every.segmented == (0, 1, 2, 3, 4) and every.delivered == (0, 2, 3, 4, 5)


def _frame(index: int, labels_box: tuple[int, int, int, int] | None = None):
    """A 480x640 frame at 2 m everywhere, and labels with a person box (r0, r1, c0, c1)."""
    depth = np.full((480, 640), 2.0, np.float32)
    rgb = np.zeros((480, 640, 3), np.uint8)
    labels = np.zeros((480, 640), np.uint8)
    if labels_box is not None:
        r0, r1, c0, c1 = labels_box
        labels[r0:r1, c0:c1] = PERSON
    return Frame(index, index / 30.0, rgb, rgb[..., 0], depth), labels


def _pose(tx: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = tx
    return pose


def _columns(region: np.ndarray) -> tuple[int, int]:
    cols = np.nonzero(region.any(axis=0))[0]
    return int(cols.min()), int(cols.max())


def test_the_mask_is_carried_by_the_previous_tracked_pose_and_replaced_when_the_next_arrives():
    semantic = SemanticFilter()  # person, dilated 5 px
    f0, lab0 = _frame(0, (200, 280, 300, 340))
    f1, lab1 = _frame(1, (100, 140, 100, 160))
    plan = schedule(np.arange(40) / 30.0, 0.5)  # segmented 0, 1, 16, 31; delivered 0, 16, 31
    carrier = Carrier(plan, {0: lab0, 1: lab1}, K, [semantic])
    # frame 0: its own mask (the wait), exactly as per-frame masks blank it
    region0 = carrier.region(f0)
    assert np.array_equal(region0, dynamic_mask(f0, lab0, [semantic]))
    carrier.tracked(f0, _pose(0.0))
    carrier.tracked(f1, _pose(0.1))  # frame 1 tracked 0.1 m to the right (its mask: pending)
    f2, _ = _frame(2)
    # frame 2 before tracking: frame 0's box carried by frame 1's pose, 500 * 0.1 / 2 = 25 px
    # to the left (splatted over the 4 px grid, dilated 5 px)
    c0, c1 = _columns(carrier.region(f2))
    assert abs(c0 - (300 - 25 - 5)) <= 5 and abs(c1 - (340 - 25 + 5)) <= 6
    assert carrier.delivered == 1
    carrier.tracked(f2, None)  # a frame without a pose: the carrying pose stays frame 1's
    f15, _ = _frame(15)
    assert _columns(carrier.region(f15)) == (c0, c1)
    carrier.tracked(f15, _pose(0.1))
    # frame 16: frame 1's mask arrives, carried from frame 1's pose to frame 15's (the same)
    f16, _ = _frame(16)
    region16 = carrier.region(f16)
    assert carrier.delivered == 2
    c0, c1 = _columns(region16)
    assert abs(c0 - (100 - 5)) <= 5 and abs(c1 - (160 + 5)) <= 6
    assert not region16[200:280, 300:340].any()  # frame 0's box is no longer blanked


def test_a_segmented_frame_without_a_pose_gives_no_mask():
    semantic = SemanticFilter()
    f0, lab0 = _frame(0, (200, 280, 300, 340))
    f1, lab1 = _frame(1, (100, 140, 100, 160))
    carrier = Carrier(schedule(np.arange(40) / 30.0, 0.5), {0: lab0, 1: lab1}, K, [semantic])
    carrier.region(f0)
    carrier.tracked(f0, _pose(0.0))
    carrier.tracked(f1, None)  # frame 1 lost: its mask cannot be carried
    f16, _ = _frame(16)
    region = carrier.region(f16)
    assert carrier.delivered == 1 and region[200:280, 300:340].all()


def _cfg(overrides: list[str]):
    from shared_helpers import compose_slam_eval

    return compose_slam_eval(overrides)


def test_orbslam3_with_the_thread_runs_and_reports_its_masks(synthetic_sequence, tmp_path):
    pytest.importorskip("pyorbslam3")
    from uss_slam.slam_eval.run import run

    seq = synthetic_sequence(preset="walking_xyz", frames=20, size=(320, 240))
    vocab = tmp_path / "voc.txt"
    build_from_sequences([seq], vocab, k=6, levels=2, stride=4)
    base = [f"sequence.path={seq}", "system=orbslam3", f"system.vocabulary={vocab}",
            "system.repeats=1", "system.realtime=false", "segmenter=labels", "segment=thread",
            "progress=false"]  # fmt: skip
    with pytest.raises(UssSlamError, match=r"^system=orbslam3 segment=thread: the segmenter"):
        run(_cfg([*base, "segmenter.latency_s=0.2", "segmenter.wait=true", f"out_dir={tmp_path}"]))
    out = tmp_path / "run"
    run(_cfg([*base, "segmenter.latency_s=0.2", f"out_dir={out}"]))
    metrics = json.loads((out / "metrics.json").read_text())
    thread = metrics["semantic_thread"]
    stamps = [float(line.split()[0]) for line in (seq / "rgb.txt").read_text().splitlines()
              if line and not line.startswith("#")]  # fmt: skip
    plan = schedule(stamps, 0.2)
    assert thread["latency_s"] == 0.2 and thread["segmented"] == len(plan.segmented)
    arrived = sum(d < len(stamps) for d in plan.delivered)
    assert 1 <= thread["delivered"][0] <= arrived
    assert 0 < metrics["blanked"]["fraction"] < 0.5
    assert metrics["frames"] == len(stamps) and thread["carry_ms"] > 0

"""studies/walking_xyz_masks.py: its recording leaves ``uss-slam``'s run unchanged and its counts
add up to the run's own; its figures, windows and errors are exact."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import colour_model, segmenter_props

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.pipelines.runs import SlamJob, run_slam
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.testing.scripts import load_script

study = load_script(Path(__file__).resolve().parents[2] / "studies" / "walking_xyz_masks.py")
FrameRecord, RunRecord = study.FrameRecord, study.RunRecord
FRAMES = 20


@pytest.fixture(scope="module")
def walkers(synthetic_sequence) -> Path:
    return synthetic_sequence(preset="walking_xyz", frames=FRAMES)


def test_runs_are_uss_slams_and_their_counts_add_up(walkers, tmp_path) -> None:
    model = colour_model(tmp_path / "colour.onnx", segmenter_props(CLASS_NAMES))
    render = study.read_render(walkers)
    assert sorted(render.people) == list(range(FRAMES)) and max(render.area.values()) > 0
    for spec in ("none", "labels", f"colour={model}"):
        m = study.parse_model(spec)
        run = study.run_model(render, m, tmp_path / "study", window=5)
        plain = run_slam(
            SlamJob(walkers, m.segmenter, m.filters, ("slam.repeats=1",)), tmp_path / m.name
        )
        # The same trajectory, file for file, as the unwrapped uss-slam run.
        assert (tmp_path / "study" / f"{walkers.name}_{m.name}" / "trajectory.txt").read_text() == (
            tmp_path / m.name / "trajectory.txt"
        ).read_text()
        assert run.ate_mm == pytest.approx(1000 * plain["ate"]["rmse"])
        assert [f.index for f in run.frames] == list(range(FRAMES))
        assert sum(f.keypoints for f in run.frames) == plain["keypoints"]["extracted"]
        kept = sum(f.keypoints - f.walker_removed - f.static_removed for f in run.frames)
        assert kept == plain["keypoints"]["kept"]
        assert sum(f.tracked for f in run.frames) == plain["frames_tracked"]
        assert all(0 <= f.on <= f.inliers and 0 <= f.origin <= f.inliers for f in run.frames)
        assert all(0 <= f.created_on <= f.created for f in run.frames)
        assert len(run.window_rpe_mm) == FRAMES // 5 - (FRAMES % 5 == 0)
        assert [w[0] for w in run.window_rpe_mm] == [5 * k for k in range(len(run.window_rpe_mm))]
        walker = sum(f.walker for f in run.frames)
        removed = sum(f.walker_removed for f in run.frames)
        assert walker > 0
        if m.name == "none":
            assert removed == 0 and all(f.hit_pixels == -1 for f in run.frames)
        elif m.name == "labels":  # the dilated true mask holds every walker keypoint
            assert removed == walker
        else:  # the model's person pixels on the walkers, as the segmenter gives them
            seg = OnnxSegmenter(model, threads=1)
            frame = TumSequence(walkers).load(3)
            truth = render.people[3]
            hits = int(((seg.infer(frame.rgb) == study.PERSON) & truth).sum())
            assert run.frames[3].hit_pixels == hits and run.frames[3].gt_pixels == truth.sum()


def _f(index, walker, removed, static_removed=0, inliers=100, on=0, origin=0, created=0,
       created_on=0, gt=0, hit=-1, tracked=True) -> FrameRecord:  # fmt: skip
    return FrameRecord(index, tracked, 200, walker, removed, static_removed, inliers, on, origin,
                       created, created_on, gt, hit)  # fmt: skip


def test_summary_figures_are_exact() -> None:
    frames = [
        _f(0, 20, 0, 10, on=10, origin=5, created=50, created_on=10, gt=100, hit=0),
        _f(1, 20, 20, 0, on=0, gt=100, hit=80),
        _f(2, 5, 5, 0, on=30, origin=30, created=40, created_on=4, gt=50, hit=10),
        _f(3, 40, 10, 30, inliers=0, tracked=False, gt=0, hit=0),
    ]
    s = study.summary(RunRecord("seq", "m", 12.5, frames))
    assert s["walker_kp"] == pytest.approx(85 / 4)
    assert s["walker_removed"] == pytest.approx(35 / 85)
    assert s["static_removed_kp"] == pytest.approx(40 / 4)
    assert s["static_removed"] == pytest.approx(40 / (800 - 85))
    assert s["walker_share_raw"] == pytest.approx(85 / 800)
    assert s["walker_share_kept"] == pytest.approx((85 - 35) / (800 - 35 - 40))
    assert s["pixel_recall"] == pytest.approx((0 + 0.8 + 0.2) / 3)  # frames with walker pixels
    # Cover over frames with >= 10 walker keypoints: 0, 1, 0.25 (frame 2 has 5).
    assert study.cover(frames).tolist() == [0.0, 1.0, 0.25]
    assert s["cover_missed"] == pytest.approx(1 / 3) and s["cover_covered"] == pytest.approx(1 / 3)
    assert s["cover_flicker"] == pytest.approx((1.0 + 0.75) / 2)
    assert s["tracked"] == 3 and s["inliers"] == pytest.approx(100)
    assert s["on_pooled"] == pytest.approx(40 / 300) and s["on_frames_over"] == 1
    assert s["from_pooled"] == pytest.approx(35 / 300)
    assert s["created_on"] == pytest.approx(14 / 90)
    assert s["created_on_in_missed"] == pytest.approx(10 / 14)  # frame 0 is missed


def test_windows_and_the_rank_correlation() -> None:
    frames = [_f(i, 10, i % 2 * 10, on=i, inliers=10) for i in range(6)]
    run = RunRecord("seq", "m", 1.0, frames, window_rpe_mm=[(0, 7.0), (3, 2.0)])
    ws = study.windows(run, 3)
    assert [w["start"] for w in ws] == [0, 3] and [w["rpe_mm"] for w in ws] == [7.0, 2.0]
    assert ws[0]["on"] == pytest.approx(3 / 30) and ws[1]["on"] == pytest.approx(12 / 30)
    assert ws[0]["cover"] == pytest.approx(10 / 30) and ws[1]["cover"] == pytest.approx(20 / 30)
    assert study.spearman([1, 2, 3, 4], [10, 20, 30, 40]) == pytest.approx(1.0)
    assert study.spearman([1, 2, 3, 4], [4, 3, 2, 1]) == pytest.approx(-1.0)
    assert study.spearman([1, 2, 2, 3], [1, 2, 3, 4]) == pytest.approx(np.corrcoef(
        [1, 2.5, 2.5, 4], [1, 2, 3, 4])[0, 1])  # fmt: skip
    assert study.spearman([1, 2], [1, 2]) is None and study.spearman([1, 1, 1], [1, 2, 3]) is None


def test_tables_and_json(walkers, tmp_path, capsys) -> None:
    out = tmp_path / "w.json"
    args = ["--sequence", str(walkers), "--model", "none", "--model", "labels"]
    assert study.main([*args, "--max-frames", "12", "--window", "4", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"### `{walkers.name}`\n\n12 frames, walkers in ")
    assert "| none | " in text and "| labels | " in text and "| 0–4 | " in text
    assert "Spearman rank correlation" in text
    data = json.loads(out.read_text())[walkers.name]
    assert [r["model"] for r in data["runs"]] == ["none", "labels"]
    assert all(len(r["frames"]) == 12 for r in data["runs"])
    assert data["runs"][1]["walker_removed"] == 1.0 and data["runs"][0]["walker_removed"] == 0.0


def test_bad_input_is_one_line(tmp_path, capsys) -> None:
    missing = tmp_path / "nope"
    bare = tmp_path / "bare"
    bare.mkdir()
    cases = [
        ([], "--sequence: required (a labelled TUM folder)"),
        (["--sequence", str(bare)], "--model: required (none, labels or NAME=PATH.onnx)"),
        (["--sequence", str(missing), "--model", "none"], f"--sequence {missing}: no such folder"),
        (["--sequence", str(bare), "--model", "m"],
         "--model 'm': expected none, labels or NAME=PATH.onnx"),
        (["--sequence", str(bare), "--model", f"m={missing}.onnx"],
         f"--model m: {missing}.onnx: no such file (expected an ONNX export)"),
        (["--sequence", str(bare), "--model", "none", "--model", "none"],
         "--model: names must differ, got none, none"),
        (["--sequence", str(bare), "--model", "none"],
         f"--sequence {bare}: no labels/ folder (expected a synthetic sequence)"),
        (["--sequence", str(bare), "--model", "none", "--split", "nope"],
         "--split 'nope': expected a comma-separated list of walkers, static, moved"),
        (["--sequence", str(bare), "--model", "none", "--window", "0"],
         "--window: expected an integer >= 1, got 0"),
        (["--sequence", str(bare), "--model", "none", "--max-frames", "1"],
         "--max-frames: expected an integer >= 2, got 1"),
        (["--sequence", str(bare), "--model", "none", "--json", str(missing / "a.json")],
         f"--json {missing / 'a.json'}: no such folder {missing}"),
    ]  # fmt: skip
    for argv, line in cases:
        assert study.main(argv) == 1, argv
        assert capsys.readouterr().err == f"walking_xyz_masks: error: {line}\n"
    with pytest.raises(SystemExit) as exit_info:
        study.main(["--help"])
    assert exit_info.value.code == 0
    assert "NAME=PATH.onnx" in capsys.readouterr().out


def test_split_runs_each_part_of_the_mask(walkers, tmp_path) -> None:
    model = colour_model(tmp_path / "colour.onnx", segmenter_props(CLASS_NAMES))
    assert [m.name for m in study.split(study.parse_model("none"))] == ["none"]
    full, on, off = study.split(study.parse_model(f"colour={model}"), ("walkers", "static"))
    assert (on.name, on.part, off.name, off.part) == ("colour:walkers", "walkers",
                                                      "colour:static", "static")  # fmt: skip
    render = study.read_render(walkers, max_frames=10)
    runs = [study.run_model(render, m, tmp_path, window=5, max_frames=10) for m in (full, on, off)]
    hits = [f.hit_pixels for f in runs[0].frames]
    assert sum(hits) > 0 and [f.hit_pixels for f in runs[1].frames] == hits
    assert all(f.hit_pixels == 0 for f in runs[2].frames)
    # The keypoints are the same; the full mask removes what either part removes, no more.
    for whole, a, b in zip(*(r.frames for r in runs), strict=True):
        assert whole.keypoints == a.keypoints == b.keypoints and whole.walker == a.walker
        for key in ("walker_removed", "static_removed"):
            parts = (getattr(a, key), getattr(b, key))
            assert max(parts) <= getattr(whole, key) <= sum(parts)
    assert sum(f.static_removed for f in runs[2].frames) > 0


def test_moved_hits_take_as_many_walker_pixels_on_the_other_side() -> None:
    truth = np.zeros((5, 12), bool)
    truth[1:4, 1:11] = True  # a 3 x 10 walker, centroid column 5.5
    hits = np.zeros_like(truth)
    hits[1:4, 1:3] = True  # its two left columns, centroid column 1.5
    moved = study.moved_hits(hits, truth)
    expected = np.zeros_like(truth)
    expected[1:4, 9:11] = True  # reflected: column 9.5, the two right columns
    np.testing.assert_array_equal(moved, expected)
    assert not study.moved_hits(np.zeros_like(truth), truth).any()
    np.testing.assert_array_equal(study.moved_hits(truth, truth), truth)


def test_split_parts_parse() -> None:
    assert study.parse_parts("walkers, moved") == ("walkers", "moved")
    assert study.parse_parts(",".join(study.PARTS)) == study.PARTS
    for text in ("", "walkers,nope"):
        with pytest.raises(study.UssSlamError, match="expected a comma-separated list of walkers"):
            study.parse_parts(text)


def test_moved_run_removes_as_many_walker_pixels(walkers, tmp_path) -> None:
    model = colour_model(tmp_path / "colour.onnx", segmenter_props(CLASS_NAMES))
    full, moved = study.split(study.parse_model(f"colour={model}"), ("moved",))
    assert moved.name == "colour:moved"
    render = study.read_render(walkers, max_frames=8)
    runs = [study.run_model(render, m, tmp_path, window=4, max_frames=8) for m in (full, moved)]
    # The same count of walker pixels per frame, all of them on the walkers.
    assert [f.hit_pixels for f in runs[1].frames] == [f.hit_pixels for f in runs[0].frames]

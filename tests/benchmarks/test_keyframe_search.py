"""benchmarks/keyframe_search.py: the keyframe matches of a run counted by caller, the all-pairs
cost of the final map, and one line for a folder without stretches."""

from __future__ import annotations

from pathlib import Path

import pytest

from uss_slam.slam_eval.matching import keyframe
from uss_slam.slam_eval.tracking import tracker
from uss_slam.testing.scripts import load_script

keyframe_search = load_script(
    Path(__file__).resolve().parents[2] / "benchmarks" / "keyframe_search.py"
)


def test_a_run_counts_its_keyframe_matches_and_the_map_pair_cost(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="handheld_rpy", frames=20, size=(320, 240))
    r = keyframe_search.run_stretch(path, None, 1)
    assert tracker.match_keyframe is keyframe.match_keyframe  # the timing is undone
    assert r["frames"] == 20 and r["keyframes"] >= 2
    assert r["pairs"] == r["keyframes"] * (r["keyframes"] - 1) and r["ms_per_call"] > 0
    assert r["calls"].get("reference", 0) >= 1  # the second frame matches its reference
    assert set(r["calls"]) == set(r["cpu_s"]) <= set(keyframe_search.CALLERS)
    lines = keyframe_search.report("seq", r)
    assert lines[0].startswith(f"seq: 20 frames, {r['keyframes']} keyframes")
    assert lines[-1].startswith("  estimate, a map of 1000 keyframes: loop closing ~")


def test_a_folder_without_stretches_is_one_line(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        keyframe_search.main(["--data", str(tmp_path)])
    assert f"--data={tmp_path}: expected a folder of TUM RGB-D stretches" in capsys.readouterr().err

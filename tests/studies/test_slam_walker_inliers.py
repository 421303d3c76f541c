"""``studies/slam_walker_inliers.py``: its recording leaves the harness unchanged, and its
counting, parsing and table are exact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.segmenters.base import NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.testing.scripts import load_script

bench = load_script(Path(__file__).resolve().parents[2] / "studies" / "slam_walker_inliers.py")


def test_recording_leaves_the_run_unchanged_and_counts_its_inliers(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    people = bench._labels(TumSequence(path, load_labels=True))
    row = bench.run_harness(path, bench.Variant("default"), people)
    plain = SlamPipeline(TumSequence(path), NoSegmenter(), [], progress=False).run()
    np.testing.assert_array_equal(row.run.trajectory.positions, plain.trajectory.positions)
    np.testing.assert_array_equal(row.run.trajectory.quaternions, plain.trajectory.quaternions)
    assert [f.index for f in row.frames] == [e.index for e in plain.log]
    assert [f.tracked for f in row.frames] == [e.tracked for e in plain.log]
    assert [f.inliers for f in row.frames] == [e.inliers for e in plain.log]
    assert all(0 <= f.on <= f.inliers and 0 <= f.origin <= f.inliers for f in row.frames)
    # The walkers are in view: some inliers of the unfiltered run lie on them.
    assert sum(f.on for f in row.frames) > 0
    assert row.ate_rmse is not None


def test_on_people_reads_the_label_under_each_keypoint() -> None:
    mask = np.zeros((4, 6), bool)
    mask[1, 2] = mask[3, 5] = True
    uv = np.array([[2.0, 1.0], [2.4, 0.6], [5.2, 2.7], [0.0, 0.0], [6.5, 3.0], [-0.6, 1.0]])
    assert bench._on_people(mask, uv).tolist() == [True, True, True, False, False, False]


def test_variants_parse_typed_overrides() -> None:
    v = bench.parse_variant(
        "wide:tracker.local_radius=12,local_ba=true,local_ba_params.depth_noise=0"
    )
    assert v.name == "wide" and v.tracker == {"local_radius": 12} and v.local_ba is True
    assert v.local_ba_params == {"depth_noise": 0}
    assert bench.parse_variant("default") == bench.Variant("default")
    for spec, message in [
        ("x:tracker.nope=1", "unknown key 'nope'"),
        ("x:tracker.local_radius=abc", "local_radius expects a value like 12.0"),
        ("x:tracker.local_radius=-1", "local_radius: expected a number > 0, got -1"),
        ("x:local_ba=1", "local_ba expects true or false"),
        ("x:orb.n_features=5", "keys are tracker.<field>"),
        ("x:tracker.ratio", "expected KEY=VALUE"),
        (":tracker.ratio=0.5", "expected NAME"),
    ]:
        with pytest.raises(UssSlamError, match=message):
            bench.parse_variant(spec)


def test_summary_and_table() -> None:
    frames = [
        bench.FrameCount(0, True, 100, 0, 0),
        bench.FrameCount(1, True, 50, 25, 10),
        bench.FrameCount(2, False, 0, 0, 0),
        bench.FrameCount(3, True, 200, 20, 0),
    ]
    s = bench.summary(bench.RowResult("r", 0.0123, frames, keyframes=7))
    assert s["tracked"] == 3 and s["frames"] == 4 and s["mean_inliers"] == pytest.approx(350 / 3)
    assert s["on_mean"] == pytest.approx((0 + 0.5 + 0.1) / 3)
    assert s["on_max"] == pytest.approx(0.5) and s["frames_over"] == 1
    assert s["from_mean"] == pytest.approx((0 + 0.2 + 0) / 3)
    lines = bench.table([s]).splitlines()
    assert len(lines) == 3 and lines[1] == "|" + "---|" * 11
    assert lines[2] == "| r | 12.3 | — | 3/4 | 7 | 117 | 20.0% | 42.0% | 50.0% | 1 | 6.7% |"


def test_cli_errors_are_one_line(capsys, tmp_path) -> None:
    assert bench.main([]) == 1
    assert capsys.readouterr().err == "slam_walker_inliers: error: --sequence: required\n"
    assert bench.main(["--sequence", str(tmp_path), "--orbslam3"]) == 1
    assert "--orbslam3 needs --vocabulary" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        bench.main(["--help"])
    assert exit_info.value.code == 0
    assert "--variant" in capsys.readouterr().out

"""studies/mask_size_control.py: the threshold that matches a mask size, the grid's SLAM jobs
it reruns, and its table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import colour_segmenter as colour_model

from uss_slam.testing.scripts import load_script

mask_size_control = load_script(
    Path(__file__).resolve().parents[2] / "studies" / "mask_size_control.py"
)
base_jobs, match_threshold, person_share, table, target_frames = (
    mask_size_control.base_jobs,
    mask_size_control.match_threshold,
    mask_size_control.person_share,
    mask_size_control.table,
    mask_size_control.target_frames,
)


def test_match_threshold_finds_the_share_by_bisection() -> None:
    share = lambda t: 1.0 - t  # noqa: E731  (decreasing, as a person share is)
    assert match_threshold(share, 0.63) == pytest.approx(0.37, abs=0.01)
    assert match_threshold(share, 0.999) == 0.02  # wanted above the largest share
    assert match_threshold(share, 0.0) == 0.98  # below the smallest


def test_person_share_grows_as_the_threshold_falls(tmp_path: Path) -> None:
    model = colour_model(tmp_path / "m.onnx", bias=200.0)
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(3)]
    low, high = person_share(model, frames, 0.05), person_share(model, frames, 0.9)
    assert 0.0 <= high <= low <= 1.0 and low > high


def test_base_jobs_are_the_grids_own_with_out_resolved(tmp_path: Path) -> None:
    cells = {
        "slam/harness/walking_xyz/semantic/source_only_s0": {
            "key": {"overrides": ["sequence.path=$OUT/data/eval/walking_xyz", "filters=[semantic]"]}
        },
        "slam/harness/walking_xyz/none": {"key": {"overrides": ["filters=[]"]}},
    }
    (tmp_path / "jobs").mkdir()
    (tmp_path / "jobs" / "slam.json").write_text(json.dumps({"cells": cells}))
    jobs = base_jobs(tmp_path, "source_only_s0", ["walking_xyz"], ["harness", "orbslam3"])
    assert jobs == {
        "slam/harness/walking_xyz/semantic/source_only_s0": [
            f"sequence.path={tmp_path}/data/eval/walking_xyz",
            "filters=[semantic]",
        ]
    }
    with pytest.raises(SystemExit, match="no SLAM job of adaptsegnet_n5_s0"):
        base_jobs(tmp_path, "adaptsegnet_n5_s0", ["walking_xyz"], ["harness"])
    with pytest.raises(SystemExit, match="slam.json: cannot read the grid's SLAM jobs"):
        base_jobs(tmp_path / "nothing", "source_only_s0", ["walking_xyz"], ["harness"])
    with pytest.raises(SystemExit, match="no target training frames"):
        target_frames(tmp_path)


def test_table_pairs_by_seed() -> None:
    rows = [{"system": "harness", "variant": "semantic", "sequence": "walking_xyz",
             "base": [0.5, 0.6], "grown": [0.7, None], "like": [0.75, 0.8]}]  # fmt: skip
    text = table(rows)
    assert "| harness, semantic | walking_xyz | 0.50 / 0.60 | 0.70 / — | 0.75 / 0.80 |" in text
    assert "+0.20 (median +0.20) | -0.05 (median -0.05) |" in text

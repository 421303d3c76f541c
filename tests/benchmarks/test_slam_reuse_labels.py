"""``benchmarks/slam_reuse_labels.py``: both settings timed in one command, the same ATE both
ways, a clear error for a missing input."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from shared_helpers import colour_model, segmenter_props

from uss_slam.core.classes import CLASS_NAMES

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "slam_reuse_labels.py"


def test_times_both_settings_and_finds_the_same_repeats(synthetic_sequence, tmp_path) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=10, size=(160, 120))
    model = colour_model(tmp_path / "m.onnx", segmenter_props(CLASS_NAMES))
    args = [sys.executable, str(SCRIPT), "--sequence", str(seq), "--model", str(model)]
    done = subprocess.run([*args, "--runs", "1", "--repeats", "2"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "reuse_labels=false" in done.stdout and "reuse_labels=true" in done.stdout
    assert "| ratio true / false |" in done.stdout
    assert "Every repeat's ATE RMSE the same both ways: yes" in done.stdout
    missing = subprocess.run(
        [*args[:3], str(tmp_path / "nope"), "--model", str(model)], capture_output=True, text=True
    )
    assert missing.returncode == 2 and f"{tmp_path / 'nope'}: not found" in missing.stderr

"""studies/memory_peaks.py: a training's memory estimate is never below its measured peak (the
CI smoke training as ``uss-train`` runs it, in its own process), and ``uss-slam``'s neither
(the harness, and ORB-SLAM3 where pyorbslam3 is installed)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from uss_slam.testing.scripts import load_script

memory_peaks = load_script(Path(__file__).resolve().parents[2] / "studies" / "memory_peaks.py")


@pytest.mark.slow
def test_estimates_are_not_below_the_measured_peaks(
    tmp_path: Path, synthetic_voc, synthetic_sequence
) -> None:
    voc = synthetic_voc(images=8, size=(160, 120))
    seq = synthetic_sequence(preset="walking_xyz", frames=10, size=(160, 120))
    paths = {"voc": voc, "seq": seq, "seq640": seq, "tum": seq, "onnx": ""}
    for name in ("ci", "slam"):
        row = memory_peaks.measure(name, memory_peaks.SETTINGS[name].format(**paths), tmp_path)
        assert row["exit"] == 0, (tmp_path / f"{name}.output").read_text()[-2000:]
        assert row["held_at_check"] > 0  # the run logged its estimate
        assert row["estimate"] >= max(row["peak_rss_main"], row["peak_pss"]), row


@pytest.mark.slow
def test_orbslam3_estimate_is_not_below_its_measured_peak(
    tmp_path: Path, synthetic_sequence
) -> None:
    pytest.importorskip("pyorbslam3")
    seq = synthetic_sequence(preset="static_xyz", frames=12, size=(320, 240))
    vocab = tmp_path / "vocab.txt"
    subprocess.run([str(memory_peaks.BIN / "uss-vocab"), "build", "--out", str(vocab), str(seq)],
                   check=True, capture_output=True)  # fmt: skip
    text = memory_peaks.SETTINGS["slam-orbslam3"].format(tum=seq, vocab=vocab)
    row = memory_peaks.measure("slam-orbslam3", text, tmp_path)
    assert row["exit"] == 0, (tmp_path / "slam-orbslam3.output").read_text()[-2000:]
    assert row["held_at_check"] > 0  # the run logged its estimate
    assert row["estimate"] >= max(row["peak_rss_main"], row["peak_pss"]), row

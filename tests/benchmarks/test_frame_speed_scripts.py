"""benchmarks/frame_ring_model.py's two-core model and benchmarks/png_decode.py's comparison."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.testing.scripts import load_script

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
ring_model = load_script(BENCHMARKS / "frame_ring_model.py")
png_decode = load_script(BENCHMARKS / "png_decode.py")


def test_the_model_gives_the_slower_side_rate_and_a_ring_absorbs_bursts() -> None:
    steady = np.full(200, 10.0)
    assert ring_model.replay(steady, np.full(200, 5.0), 4) == pytest.approx(100.0, rel=0.01)
    assert ring_model.replay(np.full(200, 5.0), steady, 4) == pytest.approx(100.0, rel=0.01)
    bursts = np.where(np.arange(200) % 10 == 0, 50.0, 5.0)  # mean 9.5 ms, every 10th 50 ms
    rates = [ring_model.replay(steady, bursts, ring) for ring in (1, 4, 16)]
    assert rates[0] < rates[1] < rates[2] <= 100.0


def test_png_decode_compares_both_ways(capsys) -> None:
    pytest.importorskip("isal")
    image = np.random.default_rng(0).integers(0, 255, (24, 32, 3)).astype(np.uint8)
    data = cv2.imencode(".png", image)[1].tobytes()
    assert png_decode.compare("rgb", [data, data], cv2.IMREAD_COLOR, rounds=2)
    line = capsys.readouterr().out
    assert line.startswith("rgb") and "same pixels: True" in line

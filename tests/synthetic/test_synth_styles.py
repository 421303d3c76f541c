"""The two styles differ measurably: a fixed colour statistic separates them."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.tum_io import read_file_list


def _histograms(root: Path, step: int = 3) -> list[np.ndarray]:
    """Normalised 8x8x8 RGB histograms of every ``step``-th colour frame."""
    out = []
    rgb = read_file_list(root / "rgb.txt")
    for i in range(0, len(rgb), step):
        img = cv2.imread(str(rgb.resolve(i)))
        hist = cv2.calcHist([img], [0, 1, 2], None, [8, 8, 8], [0, 256] * 3).reshape(-1)
        out.append((hist / hist.sum()).astype(np.float32))
    return out


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(cv2.compareHist(a, b, cv2.HISTCMP_BHATTACHARYYA))


def test_colour_histogram_distance_separates_the_styles(synthetic_sequence) -> None:
    """Within a style, frames (different views, people moving) are closer to each other than
    any source frame is to any target frame, for two presets."""
    for preset in ("walking_xyz", "sitting_static"):
        src = _histograms(
            synthetic_sequence(preset=preset, frames=30, size=(320, 240), style="source")
        )
        tgt = _histograms(
            synthetic_sequence(preset=preset, frames=30, size=(320, 240), style="target")
        )
        within = [
            _distance(a, b) for group in (src, tgt) for a, b in itertools.combinations(group, 2)
        ]
        across = [_distance(a, b) for a in src for b in tgt]
        assert max(within) < min(across), (preset, max(within), min(across))


def test_target_style_is_noisier_and_softer(synthetic_sequence) -> None:
    """Sensor noise and blur: more energy in flat regions, less at edges, than the clean render."""
    src = synthetic_sequence(preset="walking_xyz", frames=30, size=(320, 240), style="source")
    tgt = synthetic_sequence(preset="walking_xyz", frames=30, size=(320, 240), style="target")
    for i in (5, 20):
        a = cv2.imread(str(read_file_list(src / "rgb.txt").resolve(i)), cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(str(read_file_list(tgt / "rgb.txt").resolve(i)), cv2.IMREAD_GRAYSCALE)
        lap_a = cv2.Laplacian(a.astype(np.float32), cv2.CV_32F)
        lap_b = cv2.Laplacian(b.astype(np.float32), cv2.CV_32F)
        flat = cv2.dilate((np.abs(lap_a) > 0).astype(np.uint8), np.ones((3, 3))) == 0
        assert flat.mean() > 0.05
        assert np.abs(lap_b[flat]).mean() > 2 * max(np.abs(lap_a[flat]).mean(), 0.5)
        strong = np.abs(lap_a) > 60
        assert np.abs(lap_b[strong]).mean() < 0.8 * np.abs(lap_a[strong]).mean()

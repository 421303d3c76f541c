"""Fixtures of the SLAM-harness tests: tiny TUM sequences written in the exact real file format,
and textured test images."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.core.tum_io import (
    TUM_CAMERAS,
    Trajectory,
    write_file_list,
    write_trajectory,
)

SequenceWriter = Callable[..., Path]


def textured(size: tuple[int, int], seed: int = 0) -> np.ndarray:
    """``(H, W)`` uint8 texture of random grey squares and discs at many scales over smooth
    noise: sharp corners everywhere, so FAST finds plenty at every pyramid level."""
    w, h = size
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.random((h // 16 + 2, w // 16 + 2)), (w, h), interpolation=cv2.INTER_CUBIC)
    img = (60 + 120 * img).astype(np.uint8)
    count = w * h // 60
    for x, y, r, g, disc in zip(
        rng.integers(0, w, count),
        rng.integers(0, h, count),
        np.rint(2 + 20 * rng.random(count) ** 3).astype(int),
        rng.integers(0, 256, count),
        rng.random(count) < 0.5,
        strict=True,
    ):
        if disc:
            cv2.circle(img, (int(x), int(y)), int(r), int(g), -1, lineType=cv2.LINE_AA)
        else:
            cv2.rectangle(img, (int(x - r), int(y - r)), (int(x + r), int(y + r)), int(g), -1)
    return img


@pytest.fixture
def texture() -> Callable[..., np.ndarray]:
    """The :func:`textured` image maker (test modules here are not a package)."""
    return textured


@pytest.fixture
def write_sequence(tmp_path: Path) -> SequenceWriter:
    """``write_sequence(n=6, size=(32, 24), depth_offset=0.004, labels=True, intrinsics=True,
    groundtruth=True, name="seq") -> Path``: a TUM RGB-D folder with known pixel values.

    Frame ``i``: rgb pixel (0, 0) = (i, 2i, 3i) in RGB order, depth = (1000 + i) units everywhere
    (5000 = 1 m), labels = i % 4; depth stamps are the rgb stamps + ``depth_offset`` seconds.
    """

    def write(
        n: int = 6,
        size: tuple[int, int] = (32, 24),
        depth_offset: float = 0.004,
        labels: bool = True,
        intrinsics: bool = True,
        groundtruth: bool = True,
        name: str = "seq",
    ) -> Path:
        root = tmp_path / name
        for sub in ("rgb", "depth", "labels"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        w, h = size
        stamps = 1305031102.175304 + np.arange(n) / 30.0
        rgb_files, depth_files = [], []
        for i, stamp in enumerate(stamps):
            rgb = np.full((h, w, 3), 50, np.uint8)
            rgb[0, 0] = (i, 2 * i, 3 * i)
            name_rgb = f"rgb/{stamp:.6f}.png"
            cv2.imwrite(str(root / name_rgb), rgb[:, :, ::-1])  # cv2 writes BGR
            name_depth = f"depth/{stamp + depth_offset:.6f}.png"
            cv2.imwrite(str(root / name_depth), np.full((h, w), 1000 + i, np.uint16))
            if labels:
                cv2.imwrite(
                    str(root / "labels" / f"{stamp:.6f}.png"), np.full((h, w), i % 4, np.uint8)
                )
            rgb_files.append(name_rgb)
            depth_files.append(name_depth)
        write_file_list(root / "rgb.txt", stamps, rgb_files)
        write_file_list(root / "depth.txt", stamps + depth_offset, depth_files, "depth maps")
        if intrinsics:
            TUM_CAMERAS["fr3"].scaled(w, h).to_yaml(root / "intrinsics.yaml")
        if groundtruth:
            gt_stamps = np.arange(stamps[0] - 0.1, stamps[-1] + 0.1, 0.01)
            poses = np.tile(np.eye(4), (len(gt_stamps), 1, 1))
            poses[:, 0, 3] = np.linspace(0, 0.1, len(gt_stamps))
            write_trajectory(root / "groundtruth.txt", Trajectory.from_matrices(gt_stamps, poses))
        return root

    return write

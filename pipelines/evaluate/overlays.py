"""Overlay PNGs of evenly spaced frames: the truth | the prediction over the image."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.classes import colorize
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import atomic_path

from .frames import LabelledFrame


def evenly_spaced(count: int, total: int) -> list[int]:
    """``count`` indices spread evenly over ``range(total)`` (all of them if fewer)."""
    if count <= 0 or total <= 0:
        return []
    if count >= total:
        return list(range(total))
    return sorted({int(round(v)) for v in np.linspace(0, total - 1, count)})


def overlay(frame: LabelledFrame, pred: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """``(H, 2W, 3)`` uint8 RGB: the truth (left) and the prediction (right) in class colours
    over the image (background and ignored pixels show the image)."""
    panels = []
    for labels in (frame.labels, pred):
        colours = colorize(labels).astype(np.float32)
        shown = (labels > 0) & (labels != 255)
        mixed = frame.rgb.astype(np.float32)
        mixed[shown] = (1 - alpha) * mixed[shown] + alpha * colours[shown]
        panels.append(np.clip(np.rint(mixed), 0, 255).astype(np.uint8))
    return np.concatenate(panels, axis=1)


def write_overlays(out: Path, kept: Sequence[tuple[LabelledFrame, np.ndarray]]) -> list[str]:
    """``overlays/NNN_<frame>.png`` in ``out`` for each kept ``(frame, prediction)``; the
    names written, relative to ``out``."""
    written: list[str] = []
    for frame, pred in kept:
        name = f"overlays/{len(written):03d}_{frame.name.replace('/', '_')}.png"
        ok, png = cv2.imencode(".png", cv2.cvtColor(overlay(frame, pred), cv2.COLOR_RGB2BGR))
        if not ok:
            raise UssSlamError(f"{out / name}: could not encode the overlay")
        with atomic_path(out / name) as tmp:
            tmp.write_bytes(png.tobytes())
        written.append(name)
    return written


def remove_stale_overlays(folder: Path, written: Sequence[str]) -> None:
    """Overlays of an earlier evaluation into the same ``--out`` that this one did not write
    (fewer ``--overlays``, other frames): removed, so that the folder holds one run's."""
    if not folder.is_dir():
        return
    mine = {Path(name).name for name in written}
    for path in folder.glob("[0-9][0-9][0-9]_*.png"):
        if path.name not in mine:
            path.unlink()
    if not any(folder.iterdir()):
        folder.rmdir()

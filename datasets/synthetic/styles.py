"""The two appearance styles. They change pixels and depth noise only, never geometry or labels.

- ``source``: clean, sharp, evenly lit; depth is exact (quantised to the PNG's 1/5000 m).
- ``target``: Kinect-like: motion blur along the camera motion during the exposure, a soft
  lens, signal-dependent sensor noise, a warm colour cast, vignetting and slow auto-exposure
  drift; depth with distance-dependent noise, no data below 0.4 m, and holes along depth edges.

Both drop depth beyond :data:`MAX_DEPTH`.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..tum_io import DEPTH_SCALE

STYLES = ("source", "target")
MAX_DEPTH = 4.5
"""Depth beyond this many metres is stored as 0 (no measurement), as a Kinect's range."""
MIN_DEPTH_TARGET = 0.4
EXPOSURE_TIME = 0.02
"""Seconds the target-style shutter stays open (length of the motion blur)."""
BLUR_TAPS = 5


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """``[0, 1]`` float RGB -> uint8 with round-to-nearest (deterministic)."""
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def depth_to_png(depth: np.ndarray) -> np.ndarray:
    """Metres -> uint16 at :data:`~uss_slam.datasets.tum_io.DEPTH_SCALE`; invalid / far -> 0."""
    valid = np.isfinite(depth) & (depth > 0) & (depth <= MAX_DEPTH)
    out = np.zeros(depth.shape, np.uint16)
    out[valid] = np.rint(depth[valid] * DEPTH_SCALE).astype(np.uint16)
    return out


def motion_blur(rgb: np.ndarray, flow: np.ndarray, taps: int = BLUR_TAPS) -> np.ndarray:
    """Average of ``taps`` samples along each pixel's motion ``flow`` (H, W, 2) during the exposure.

    ``flow`` is where the pixel's scene point was, relative to now, when the shutter opened.
    """
    h, w = rgb.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    acc = np.zeros_like(rgb)
    for s in np.linspace(0.0, 1.0, taps, dtype=np.float32):
        acc += cv2.remap(
            rgb, gx + s * flow[..., 0], gy + s * flow[..., 1], cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT,
        )  # fmt: skip
    return acc / np.float32(taps)


def exposure_gain(t: float, phase: float) -> float:
    """Slow auto-exposure drift of the target camera at ``t`` seconds."""
    return (
        1.0
        + 0.12 * math.sin(2 * math.pi * t / 4.3 + phase)
        + 0.05 * math.sin(2 * math.pi * t / 1.7 + 2 * phase)
    )


_VIGNETTE: dict[tuple[int, int], np.ndarray] = {}


def _vignette(h: int, w: int) -> np.ndarray:
    if (h, w) not in _VIGNETTE:
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((x - w / 2) / (w / 2)) ** 2 + ((y - h / 2) / (h / 2)) ** 2
        _VIGNETTE[(h, w)] = (1.0 - 0.22 * r2).astype(np.float32)[..., None]
    return _VIGNETTE[(h, w)]


def target_rgb(
    rgb: np.ndarray, flow: np.ndarray | None, gain: float, rng: np.random.Generator
) -> np.ndarray:
    """Kinect-like colour image (uint8 RGB) from a clean render ``rgb`` (H, W, 3) in [0, 1]."""
    h, w = rgb.shape[:2]
    img = motion_blur(rgb, flow) if flow is not None else rgb
    sigma = 0.55 * max(w, h) / 640  # the Kinect's soft optics
    img = cv2.GaussianBlur(img, (0, 0), sigma)
    cast = np.array([1.07, 0.98, 0.8], np.float32)
    img = img * (gain * cast) * _vignette(h, w) + np.array([0.03, 0.02, 0.05], np.float32)
    img = np.power(np.clip(img, 0, 1), np.float32(0.9))
    noise = rng.standard_normal(img.shape, dtype=np.float32)
    img = img + noise * (0.012 + 0.025 * np.sqrt(img))
    return to_uint8(img)


def target_depth(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Kinect-like depth (uint16 PNG units) from exact depth in metres (H, W)."""
    z = depth.astype(np.float32)
    # axial noise grows with the square of the distance (Nguyen et al. 2012)
    sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2
    noisy = z + sigma * rng.standard_normal(z.shape, dtype=np.float32)
    # holes where the depth jumps (shadowing between projector and camera) and a few dropouts
    zf = np.where(np.isfinite(z), z, 10.0).astype(np.float32)
    kernel = np.ones((3, 3), np.uint8)
    jump = (cv2.dilate(zf, kernel) - cv2.erode(zf, kernel)) > 0.08 * zf
    jump = cv2.dilate(jump.astype(np.uint8), kernel).astype(bool)
    holes = jump & (rng.random(z.shape, dtype=np.float32) < 0.75)
    holes |= rng.random(z.shape, dtype=np.float32) < 0.003
    noisy[holes | (z < MIN_DEPTH_TARGET)] = 0
    return depth_to_png(noisy)

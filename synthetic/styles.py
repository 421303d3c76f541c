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

from uss_slam.core.tum_io import DEPTH_SCALE

from .seeding import stream

STYLES = ("source", "target")
MAX_DEPTH = 4.5
"""Depth beyond this many metres is stored as 0 (no measurement), as a Kinect's range."""
MIN_DEPTH_TARGET = 0.4
EXPOSURE_TIME = 0.02
"""Seconds the target-style shutter stays open (length of the motion blur)."""
BLUR_TAPS = 3


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """``[0, 1]`` float RGB -> uint8 with round-to-nearest (deterministic)."""
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def depth_to_png(depth: np.ndarray) -> np.ndarray:
    """Metres -> uint16 at :data:`~uss_slam.core.tum_io.DEPTH_SCALE`; invalid / far -> 0."""
    valid = np.isfinite(depth) & (depth > 0) & (depth <= MAX_DEPTH)
    out = np.zeros(depth.shape, np.uint16)
    out[valid] = np.rint(depth[valid] * DEPTH_SCALE).astype(np.uint16)
    return out


class NoisePool:
    """Pre-drawn noise, sliced at a random offset per frame (drawing fresh noise for every
    pixel of every frame costs more than the rendering itself).

    ``normal``: int8 standard normal noise times 16; ``uniform``: uint8 uniform in [0, 256).
    """

    def __init__(self, seed: int, size: int) -> None:
        rng = stream(seed, "noise-pool")
        self.normal = np.clip(np.rint(rng.standard_normal(size) * 16), -127, 127).astype(np.int8)
        self.uniform = rng.integers(0, 256, size, dtype=np.uint8)

    def _take(self, pool: np.ndarray, rng: np.random.Generator, shape: tuple[int, ...]):
        n = int(np.prod(shape))
        start = int(rng.integers(0, len(pool) - n + 1))
        return pool[start : start + n].reshape(shape)

    def normal16(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Standard normal noise times 16 (int8)."""
        return self._take(self.normal, rng, shape)

    def uniform8(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Uniform integers in [0, 256) (uint8)."""
        return self._take(self.uniform, rng, shape)


def motion_blur(rgb: np.ndarray, flow: np.ndarray, taps: int = BLUR_TAPS) -> np.ndarray:
    """Average of ``taps`` samples along each pixel's motion during an exposure centred on now.

    ``flow`` (H, W, 2) is where the pixel's scene point was, relative to now, when the shutter
    opened; at constant velocity it is at minus that when the shutter closes. The samples are
    evenly spaced over the exposure with triangular weights (the middle one is the image
    itself). Works on uint8 images (averaged in 16 bits).
    """
    h, w = rgb.shape[:2]
    gx, gy = _grid(h, w)
    steps = np.linspace(-1.0, 1.0, taps, dtype=np.float32)
    weights = (1.0 + taps // 2 - np.abs(np.arange(taps) - taps // 2)).astype(np.uint16)
    acc = np.zeros(rgb.shape, np.uint16)
    fx, fy = np.ascontiguousarray(flow[..., 0]), np.ascontiguousarray(flow[..., 1])
    for s, weight in zip(steps, weights, strict=True):
        if s == 0:
            sample = rgb
        else:
            sample = cv2.remap(rgb, gx + s * fx, gy + s * fy, cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)  # fmt: skip
        acc += sample * weight
    total = int(weights.sum())
    return ((acc + total // 2) // total).astype(np.uint8)


_GRIDS: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}


def _grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    if (h, w) not in _GRIDS:
        _GRIDS[(h, w)] = tuple(  # type: ignore[assignment]
            np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        )
    return _GRIDS[(h, w)]


def exposure_gain(t: float, phase: float) -> float:
    """Slow auto-exposure drift of the target camera at ``t`` seconds."""
    return (
        1.0
        + 0.12 * math.sin(2 * math.pi * t / 4.3 + phase)
        + 0.05 * math.sin(2 * math.pi * t / 1.7 + 2 * phase)
    )


_VIGNETTE: dict[tuple[int, int], np.ndarray] = {}
_CAST = np.array([1.07, 0.98, 0.8], np.float32)
"""Warm colour cast of the target camera (red up, blue down)."""
_BLACK_LEVEL = np.array([0.03, 0.02, 0.05], np.float32) * 255 + 0.5  # + 0.5: round to nearest


def _vignette(h: int, w: int) -> np.ndarray:
    """Vignetting (darker corners) times the colour cast, ``(H, W, 3)`` float32."""
    if (h, w) not in _VIGNETTE:
        y, x = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((x - w / 2) / (w / 2)) ** 2 + ((y - h / 2) / (h / 2)) ** 2
        _VIGNETTE[(h, w)] = (1.0 - 0.22 * r2).astype(np.float32)[..., None] * _CAST
    return _VIGNETTE[(h, w)]


# Gamma 0.9 plus signal-dependent noise strength (photon noise grows with sqrt(intensity)):
# both as 256-entry tables applied to the 8-bit image.
_LEVELS = np.arange(256, dtype=np.float64) / 255
_GAMMA_LUT = np.rint(255 * _LEVELS**0.9).astype(np.uint8)
_NOISE_LUT = np.rint(255 * (0.012 + 0.025 * np.sqrt(_LEVELS**0.9)) * 16).astype(np.int16)
"""Noise standard deviation in 1/16 grey levels per grey level (matches ``NoisePool.normal``)."""


def target_rgb(
    rgb: np.ndarray,
    flow: np.ndarray | None,
    gain: float,
    rng: np.random.Generator,
    pool: NoisePool,
) -> np.ndarray:
    """Kinect-like colour image (uint8 RGB) from a clean render ``rgb`` (H, W, 3) in [0, 1].

    Colour cast, vignetting and exposure gain; motion blur along ``flow``; the soft optics of
    a Kinect (Gaussian, 0.55 px at 640 px); gamma; signal-dependent sensor noise.
    """
    h, w = rgb.shape[:2]
    # colour cast, vignetting, exposure and the black level in one multiply-add (in 0..255)
    img = rgb * (_vignette(h, w) * np.float32(gain * 255)) + _BLACK_LEVEL
    img8 = np.clip(img, 0, 255).astype(np.uint8)
    if flow is not None:
        img8 = motion_blur(img8, flow)
    img8 = cv2.GaussianBlur(img8, (0, 0), 0.55 * max(w, h) / 640)
    img8 = cv2.LUT(img8, _GAMMA_LUT)
    noise = pool.normal16(rng, img8.shape).astype(np.int16) * _NOISE_LUT[img8]
    out = img8.astype(np.int16) + ((noise + 128) >> 8)  # 1/16 * 1/16 = the 1/256 scale
    return np.clip(out, 0, 255).astype(np.uint8)


DEPTH_NOISE_K = 0.0019
"""k of the target style's axial depth noise ``σ_z ≈ k·z²`` (metres⁻¹; exactly
``0.0012 + k·(z - 0.4)²``), which its sequences declare in ``intrinsics.yaml`` (``depth_noise``)
for the SLAM back end's noise model."""


def target_depth(depth: np.ndarray, rng: np.random.Generator, pool: NoisePool) -> np.ndarray:
    """Kinect-like depth (uint16 PNG units) from exact depth in metres (H, W)."""
    z = depth.astype(np.float32)
    # axial noise grows with the square of the distance (Nguyen et al. 2012)
    sigma = np.float32(0.0012 / 16) + np.float32(DEPTH_NOISE_K / 16) * (z - np.float32(0.4)) ** 2
    noisy = z + sigma * pool.normal16(rng, z.shape)
    # holes where the depth jumps (shadowing between projector and camera) and a few dropouts
    zf = np.where(np.isfinite(z), z, np.float32(10.0))
    kernel = np.ones((3, 3), np.uint8)
    jump = (cv2.dilate(zf, kernel) - cv2.erode(zf, kernel)) > np.float32(0.08) * zf
    jump = cv2.dilate(jump.view(np.uint8), kernel).view(bool)
    chance = pool.uniform8(rng, z.shape)
    holes = (jump & (chance < 192)) | (chance == 255) & (pool.uniform8(rng, z.shape) < 200)
    noisy[holes | (z < MIN_DEPTH_TARGET)] = 0
    return depth_to_png(noisy)

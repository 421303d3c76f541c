"""Drawing helpers of the procedural textures: tiling noise, shapes and lettering drawn with
wrap-around (textures tile), and the colour pickers the material families share."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

RGB = tuple[int, int, int]


def periodic_noise(rng: np.random.Generator, size: int, period: float, channels: int = 1):
    """Tileable band-limited noise, ``(size, size[, channels])`` float32 with std 1.

    White noise filtered in the Fourier domain (so it wraps seamlessly) with a Gaussian low-pass
    whose cut-off corresponds to features about ``period`` texels across. Smooth noise is made
    at a coarser grid (at least 4 samples per period) and interpolated up.
    """
    factor = 1
    while period / (2 * factor) >= 4 and size // (2 * factor) >= 32:
        factor *= 2
    n = size // factor
    f = np.fft.fftfreq(n).astype(np.float32)
    fr = np.fft.rfftfreq(n).astype(np.float32)
    sigma = factor / max(period, 1.0)
    gain = np.exp(-(f[:, None] ** 2 + fr[None, :] ** 2) / (2 * sigma * sigma)).astype(np.float32)
    out = []
    for _ in range(channels):
        white = rng.standard_normal((n, n)).astype(np.float32)
        field = np.fft.irfft2(np.fft.rfft2(white) * gain, s=(n, n)).astype(np.float32)
        if factor > 1:
            tiled = np.tile(field, (3, 3))  # interpolate with wrap-around neighbours
            up = cv2.resize(tiled, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
            field = np.ascontiguousarray(up[size : 2 * size, size : 2 * size])
        field /= field.std() + 1e-6
        out.append(field)
    return out[0] if channels == 1 else np.stack(out, axis=-1)


def offsets(size: int, x0: float, y0: float, x1: float, y1: float):
    """Tile offsets at which a shape with bounding box ``(x0, y0)-(x1, y1)`` touches the canvas."""
    for dy in (-size, 0, size):
        for dx in (-size, 0, size):
            if x1 + dx >= 0 and x0 + dx < size and y1 + dy >= 0 and y0 + dy < size:
                yield dx, dy


def rect(img: np.ndarray, x: float, y: float, w: float, h: float, color: RGB, thick: int = -1):
    size = img.shape[0]
    for dx, dy in offsets(size, x, y, x + w, y + h):
        p0 = (int(x + dx), int(y + dy))
        p1 = (int(x + w + dx), int(y + h + dy))
        cv2.rectangle(img, p0, p1, color, thick, cv2.LINE_AA)


def circle(img: np.ndarray, x: float, y: float, r: float, color: RGB, thick: int = -1):
    size = img.shape[0]
    for dx, dy in offsets(size, x - r, y - r, x + r, y + r):
        cv2.circle(img, (int(x + dx), int(y + dy)), max(int(r), 1), color, thick, cv2.LINE_AA)


def poly(img: np.ndarray, pts: np.ndarray, color: RGB, closed: bool = True, thick: int = -1):
    size = img.shape[0]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    for dx, dy in offsets(size, lo[0], lo[1], hi[0], hi[1]):
        p = (pts + (dx, dy)).astype(np.int32)
        if thick < 0:
            cv2.fillPoly(img, [p], color, cv2.LINE_AA)
        else:
            cv2.polylines(img, [p], closed, color, thick, cv2.LINE_AA)


def text(img: np.ndarray, x: float, y: float, scale: float, color: RGB, rng, n: int = 8):
    letters = "ABCDEFGHKLMNOPRSTUVWXYZ0123456789"
    word = "".join(letters[i] for i in rng.integers(0, len(letters), n))
    thick = max(1, int(round(scale * 2)))
    cv2.putText(
        img, word, (int(x), int(y)), cv2.FONT_HERSHEY_SIMPLEX, scale, color, thick, cv2.LINE_AA
    )


def vivid(rng: np.random.Generator) -> RGB:
    h = rng.uniform(0, 180)
    s = rng.uniform(150, 255)
    v = rng.uniform(120, 255)
    hsv = np.array([[[h, s, v]]], dtype=np.uint8)
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


def muted(rng: np.random.Generator, lo: float = 40, hi: float = 200) -> RGB:
    h = rng.uniform(0, 180)
    s = rng.uniform(20, 110)
    v = rng.uniform(lo, hi)
    hsv = np.array([[[h, s, v]]], dtype=np.uint8)
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


def shade(color: RGB, factor: float) -> RGB:
    return tuple(int(np.clip(c * factor, 0, 255)) for c in color)


def modulate(img: np.ndarray, field: np.ndarray, amount: float) -> np.ndarray:
    out = img.astype(np.float32) * (1.0 + amount * field[..., None])
    return np.clip(out, 0, 255).astype(np.uint8)


def scatter(img: np.ndarray, rng, count: int, rmin: float, rmax: float, colors: Callable[[], RGB]):
    """Random filled shapes (discs, squares, triangles) of radius ``rmin..rmax`` texels."""
    size = img.shape[0]
    for _ in range(count):
        x, y = rng.uniform(0, size, 2)
        r = rng.uniform(rmin, rmax)
        kind = rng.integers(0, 3)
        color = colors()
        if kind == 0:
            circle(img, x, y, r, color)
        elif kind == 1:
            rect(img, x - r, y - r, 2 * r, 2 * r * rng.uniform(0.5, 1.5), color)
        else:
            ang = rng.uniform(0, 2 * np.pi) + np.array([0, 2.1, 4.2])
            pts = np.stack([x + r * np.cos(ang), y + r * np.sin(ang)], axis=1)
            poly(img, pts, color)

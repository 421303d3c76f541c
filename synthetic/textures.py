"""Procedural, mip-mapped surface textures in two families (``source`` and ``target``).

A :class:`TextureBank` holds one texture per material *role* (walls, floor, desk, shirts, ...)
and samples it per pixel. Sampling is filtered: the mip level is chosen from the pixel's
footprint on the surface (metres per pixel over metres per texel), and the level is read with
bilinear interpolation, so a static surface looks the same from nearby viewpoints instead of
shimmering (ORB matching between frames depends on that).

All levels of all materials are packed into one flat ``uint32`` array (RGBA bytes) so that a
texture lookup for every pixel of a frame is a handful of vectorised integer gathers.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from .seeding import stream

FAMILIES = ("source", "target")

ROOM_SIZE = 1024
OBJECT_SIZE = 256
PEOPLE_SLOTS = 4
"""Outfits per bank; person ``k`` of a scene wears outfit ``k % PEOPLE_SLOTS``."""


@dataclass(frozen=True)
class Role:
    """A material role: texture size (texels, power of two) and texel size (metres)."""

    name: str
    size: int
    texel: float


def _roles() -> tuple[Role, ...]:
    roles = [
        Role("wall_a", ROOM_SIZE, 0.006),
        Role("wall_b", ROOM_SIZE, 0.006),
        Role("wall_c", ROOM_SIZE, 0.006),
        Role("wall_d", ROOM_SIZE, 0.006),
        Role("floor", ROOM_SIZE, 0.006),
        Role("ceiling", ROOM_SIZE, 0.006),
        Role("desk", OBJECT_SIZE * 2, 0.004),
        Role("desk_frame", OBJECT_SIZE, 0.004),
        Role("cabinet", OBJECT_SIZE * 2, 0.004),
        Role("chair_seat", OBJECT_SIZE, 0.003),
        Role("chair_frame", OBJECT_SIZE, 0.003),
        Role("monitor_screen", OBJECT_SIZE * 2, 0.0012),
        Role("monitor_body", OBJECT_SIZE, 0.003),
        Role("clutter", OBJECT_SIZE * 2, 0.0015),
    ]
    for k in range(PEOPLE_SLOTS):
        roles += [
            Role(f"shirt_{k}", OBJECT_SIZE * 2, 0.0025),
            Role(f"trousers_{k}", OBJECT_SIZE, 0.003),
            Role(f"skin_{k}", OBJECT_SIZE, 0.003),
            Role(f"hair_{k}", OBJECT_SIZE, 0.002),
        ]
    return tuple(roles)


ROLES: tuple[Role, ...] = _roles()
ROLE_INDEX: dict[str, int] = {r.name: i for i, r in enumerate(ROLES)}


def material(name: str) -> int:
    """Material id of a role name (the same in every bank)."""
    return ROLE_INDEX[name]


# --------------------------------------------------------------------------- drawing helpers

RGB = tuple[int, int, int]


def _periodic_noise(rng: np.random.Generator, size: int, period: float, channels: int = 1):
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


def _offsets(size: int, x0: float, y0: float, x1: float, y1: float):
    """Tile offsets at which a shape with bounding box ``(x0, y0)-(x1, y1)`` touches the canvas."""
    for dy in (-size, 0, size):
        for dx in (-size, 0, size):
            if x1 + dx >= 0 and x0 + dx < size and y1 + dy >= 0 and y0 + dy < size:
                yield dx, dy


def _rect(img: np.ndarray, x: float, y: float, w: float, h: float, color: RGB, thick: int = -1):
    size = img.shape[0]
    for dx, dy in _offsets(size, x, y, x + w, y + h):
        p0 = (int(x + dx), int(y + dy))
        p1 = (int(x + w + dx), int(y + h + dy))
        cv2.rectangle(img, p0, p1, color, thick, cv2.LINE_AA)


def _circle(img: np.ndarray, x: float, y: float, r: float, color: RGB, thick: int = -1):
    size = img.shape[0]
    for dx, dy in _offsets(size, x - r, y - r, x + r, y + r):
        cv2.circle(img, (int(x + dx), int(y + dy)), max(int(r), 1), color, thick, cv2.LINE_AA)


def _poly(img: np.ndarray, pts: np.ndarray, color: RGB, closed: bool = True, thick: int = -1):
    size = img.shape[0]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    for dx, dy in _offsets(size, lo[0], lo[1], hi[0], hi[1]):
        p = (pts + (dx, dy)).astype(np.int32)
        if thick < 0:
            cv2.fillPoly(img, [p], color, cv2.LINE_AA)
        else:
            cv2.polylines(img, [p], closed, color, thick, cv2.LINE_AA)


def _text(img: np.ndarray, x: float, y: float, scale: float, color: RGB, rng, n: int = 8):
    letters = "ABCDEFGHKLMNOPRSTUVWXYZ0123456789"
    word = "".join(letters[i] for i in rng.integers(0, len(letters), n))
    thick = max(1, int(round(scale * 2)))
    cv2.putText(
        img, word, (int(x), int(y)), cv2.FONT_HERSHEY_SIMPLEX, scale, color, thick, cv2.LINE_AA
    )


def _vivid(rng: np.random.Generator) -> RGB:
    h = rng.uniform(0, 180)
    s = rng.uniform(150, 255)
    v = rng.uniform(120, 255)
    hsv = np.array([[[h, s, v]]], dtype=np.uint8)
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


def _muted(rng: np.random.Generator, lo: float = 40, hi: float = 200) -> RGB:
    h = rng.uniform(0, 180)
    s = rng.uniform(20, 110)
    v = rng.uniform(lo, hi)
    hsv = np.array([[[h, s, v]]], dtype=np.uint8)
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


def _shade(color: RGB, factor: float) -> RGB:
    return tuple(int(np.clip(c * factor, 0, 255)) for c in color)


def _modulate(img: np.ndarray, field: np.ndarray, amount: float) -> np.ndarray:
    out = img.astype(np.float32) * (1.0 + amount * field[..., None])
    return np.clip(out, 0, 255).astype(np.uint8)


def _scatter(img: np.ndarray, rng, count: int, rmin: float, rmax: float, colors: Callable[[], RGB]):
    """Random filled shapes (discs, squares, triangles) of radius ``rmin..rmax`` texels."""
    size = img.shape[0]
    for _ in range(count):
        x, y = rng.uniform(0, size, 2)
        r = rng.uniform(rmin, rmax)
        kind = rng.integers(0, 3)
        color = colors()
        if kind == 0:
            _circle(img, x, y, r, color)
        elif kind == 1:
            _rect(img, x - r, y - r, 2 * r, 2 * r * rng.uniform(0.5, 1.5), color)
        else:
            ang = rng.uniform(0, 2 * np.pi) + np.array([0, 2.1, 4.2])
            pts = np.stack([x + r * np.cos(ang), y + r * np.sin(ang)], axis=1)
            _poly(img, pts, color)


# --------------------------------------------------------------------------- source family
# Clean and flat: saturated colours, sharp geometric shapes, no noise.


def _src_wall(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(190, 245, 3))
    img = np.full((size, size, 3), base, np.uint8)
    dark = _shade(base, 0.55)
    # Wallpaper motif: a dense scatter of medium shapes (5-15 cm) in a darker shade and accents.
    _scatter(
        img, rng, size * size // 900, 4, 12, lambda: dark if rng.random() < 0.6 else _vivid(rng)
    )
    # Posters and whiteboards (30-90 cm) with inner geometry and text.
    for _ in range(rng.integers(6, 11)):
        w, h = rng.uniform(50, 150, 2)
        x, y = rng.uniform(0, size - w), rng.uniform(0, size - h)
        _rect(img, x, y, w, h, _vivid(rng))
        _rect(img, x, y, w, h, (20, 20, 20), 2)
        for _ in range(rng.integers(3, 9)):
            cx, cy = x + rng.uniform(0.1, 0.9) * w, y + rng.uniform(0.1, 0.9) * h
            r = rng.uniform(4, min(w, h) / 4)
            if rng.random() < 0.5:
                _circle(img, cx, cy, r, _vivid(rng))
            else:
                _rect(img, cx - r, cy - r, 2 * r, r, _vivid(rng))
        _text(img, x + 4, y + h - 6, rng.uniform(0.35, 0.7), (15, 15, 15), rng)
    return img


def _src_floor(rng, size: int) -> np.ndarray:
    a = tuple(int(c) for c in rng.integers(120, 220, 3))
    b = _shade(a, 0.6)
    img = np.full((size, size, 3), a, np.uint8)
    tile = size // int(rng.choice([8, 16]))
    for ty in range(0, size, tile):
        for tx in range(0, size, tile):
            if ((tx // tile) + (ty // tile)) % 2:
                _rect(img, tx, ty, tile - 1, tile - 1, b)
            # an inlay per tile gives corners at every tile, not only at the grout
            r = tile * rng.uniform(0.12, 0.3)
            cx, cy = tx + tile * rng.uniform(0.3, 0.7), ty + tile * rng.uniform(0.3, 0.7)
            _circle(img, cx, cy, r, _vivid(rng)) if rng.random() < 0.5 else _rect(
                img, cx - r, cy - r, 2 * r, 2 * r, _vivid(rng)
            )
    for y in range(0, size, tile):
        cv2.line(img, (0, y), (size, y), (40, 40, 40), 2)
        cv2.line(img, (y, 0), (y, size), (40, 40, 40), 2)
    return img


def _src_ceiling(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(215, 250, 3))
    img = np.full((size, size, 3), base, np.uint8)
    panel = size // 10
    _scatter(img, rng, size * size // 700, 2, 5, lambda: _shade(base, 0.7))
    for p in range(0, size, panel):
        cv2.line(img, (0, p), (size, p), (110, 110, 120), 3)
        cv2.line(img, (p, 0), (p, size), (110, 110, 120), 3)
    for _ in range(6):
        x, y = rng.integers(0, 10, 2) * panel
        _rect(img, x + 6, y + 6, panel - 12, panel - 12, (255, 255, 235))
        _rect(img, x + 6, y + 6, panel - 12, panel - 12, (90, 90, 90), 2)
    return img


def _src_desk(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(150, 235, 3))
    img = np.full((size, size, 3), base, np.uint8)
    for _ in range(rng.integers(10, 20)):  # papers, notebooks, keyboards
        w, h = rng.uniform(25, 90, 2)
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, w, h, _vivid(rng) if rng.random() < 0.5 else (245, 245, 245))
        _text(img, x + 3, y + h / 2, 0.3, (20, 20, 20), rng, 5)
    _scatter(img, rng, 120, 2, 6, lambda: _shade(base, 0.6))
    return img


def _src_solid_pattern(rng, size: int, base: RGB, accent: float = 0.65, count: int = 200):
    img = np.full((size, size, 3), base, np.uint8)
    _scatter(img, rng, count, 2, 5, lambda: _shade(base, accent))
    return img


def _src_cabinet(rng, size: int) -> np.ndarray:
    img = np.full((size, size, 3), tuple(int(c) for c in rng.integers(100, 200, 3)), np.uint8)
    shelf = size // 4
    for sy in range(0, size, shelf):
        x = 0.0
        while x < size:  # books of random width and colour
            w = rng.uniform(6, 18)
            h = rng.uniform(0.6, 0.92) * shelf
            _rect(img, x, sy + shelf - h, w - 1, h, _vivid(rng))
            x += w
        cv2.line(img, (0, sy), (size, sy), (30, 30, 30), 4)
    return img


def _src_screen(rng, size: int) -> np.ndarray:
    img = np.full((size, size, 3), _vivid(rng), np.uint8)
    for _ in range(rng.integers(4, 8)):  # windows with title bars and text lines
        w, h = rng.uniform(100, 300, 2)
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, w, h, (250, 250, 250))
        _rect(img, x, y, w, 14, _vivid(rng))
        for line in range(int(h // 16) - 1):
            _text(img, x + 6, y + 30 + 16 * line, 0.4, (30, 30, 30), rng, int(rng.integers(4, 14)))
    return img


def _contrasting(rng: np.random.Generator, colour_fn) -> tuple[RGB, RGB]:
    """Two colours from ``colour_fn`` whose grey levels differ by at least 90 (ORB sees grey)."""
    grey = lambda c: 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]  # noqa: E731
    a = colour_fn()
    for _ in range(50):
        b = colour_fn()
        if abs(grey(a) - grey(b)) >= 90:
            return a, b
    return a, (20, 20, 20) if grey(a) > 128 else (235, 235, 235)


def _print(img: np.ndarray, rng, colours: tuple[RGB, RGB], count: int, rmin: float, rmax: float):
    """Clothing print: shapes in the two contrasting colours plus lettering."""
    _scatter(img, rng, count, rmin, rmax, lambda: colours[int(rng.integers(0, 2))])
    size = img.shape[0]
    for _ in range(size // 48):
        x, y = rng.uniform(0, size - 60, 2)
        _text(img, x, y, rng.uniform(0.5, 0.9), colours[int(rng.integers(0, 2))], rng, 4)


def _src_clutter(rng, size: int) -> np.ndarray:
    """Boxes, book covers and packaging: colour blocks with labels, logos and bar codes."""
    img = np.full((size, size, 3), _vivid(rng), np.uint8)
    for _ in range(40):
        w, h = rng.uniform(30, 140, 2)
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, w, h, _vivid(rng))
        _text(img, x + 4, y + h * 0.6, rng.uniform(0.4, 0.8), (15, 15, 15), rng, 5)
        for k in range(int(rng.integers(0, 12))):  # bar code
            _rect(img, x + 4 + 3 * k, y + 4, 1, 12, (10, 10, 10))
    _scatter(img, rng, 300, 3, 8, lambda: _vivid(rng))
    return img


def _src_shirt(rng, size: int) -> np.ndarray:
    a, b = _contrasting(rng, lambda: _vivid(rng))
    img = np.full((size, size, 3), a, np.uint8)
    kind = rng.integers(0, 3)
    step = int(rng.integers(16, 32))
    if kind == 0:  # stripes
        for y in range(0, size, step):
            _rect(img, 0, y, size, step // 2, b)
    elif kind == 1:  # checks
        for y in range(0, size, step):
            for x in range(0, size, step):
                if (x // step + y // step) % 2:
                    _rect(img, x, y, step - 1, step - 1, b)
    _print(img, rng, (a, b) if kind == 2 else _contrasting(rng, lambda: _vivid(rng)), 700, 3, 8)
    return img


def _wardrobe_colour(rng) -> RGB:
    """Any clothing colour: saturated or muted, light or dark (the varied wardrobe)."""
    return _vivid(rng) if rng.random() < 0.5 else _muted(rng, 25, 235)


def _varied_shirt(rng, size: int) -> np.ndarray:
    """A shirt of the varied wardrobe: any colours, and one of six kinds of fabric.

    Real photo sets show people in every kind of clothing; the classic source shirts are only
    saturated stripes, checks and prints. Plain, striped, checked, plaid, blotched and printed
    fabrics in saturated or muted colours, with a weave texture of random strength.
    """
    a, b = _contrasting(rng, lambda: _wardrobe_colour(rng))
    img = np.full((size, size, 3), a, np.uint8)
    kind = int(rng.integers(0, 6))
    step = int(rng.integers(16, 56))
    if kind == 1:  # stripes, either way
        for p in range(0, size, step):
            if rng.random() < 0.5:
                _rect(img, 0, p, size, step // 2, b)
            else:
                _rect(img, p, 0, step // 2, size, b)
    elif kind == 2:  # checks
        for y in range(0, size, step):
            for x in range(0, size, step):
                if (x // step + y // step) % 2:
                    _rect(img, x, y, step - 1, step - 1, b)
    elif kind == 3:  # plaid
        for p in range(0, size, step):
            _rect(img, p, 0, step // 3, size, b)
            _rect(img, 0, p, size, step // 3, _shade(b, 0.7))
    elif kind == 4:  # blotches
        n = _periodic_noise(rng, size, rng.uniform(4, 12))
        img = np.where((n > rng.uniform(-0.3, 0.5))[..., None], np.array(a, np.uint8),
                       np.array(b, np.uint8)).astype(np.uint8)  # fmt: skip
        img = np.ascontiguousarray(img)
    elif kind == 5:  # print
        _print(img, rng, (a, b), int(rng.integers(100, 700)), 3, 8)
    # kind 0: plain, with the seams and a few marks below
    _scatter(
        img, rng, int(rng.integers(20, 200)), 2, 6, lambda: _shade(a, float(rng.choice([0.5, 1.6])))
    )
    return _modulate(img, _periodic_noise(rng, size, rng.uniform(1.0, 3.0)), rng.uniform(0.0, 0.2))


def _varied_trousers(rng, size: int) -> np.ndarray:
    """Trousers of the varied wardrobe: dark saturated, denim or muted, with seams."""
    pick = rng.random()
    if pick < 0.35:
        base = _shade(_vivid(rng), 0.45)
    elif pick < 0.7:
        base = tuple(int(c) for c in np.array((50, 70, 120)) * rng.uniform(0.6, 1.4))
    else:
        base = _muted(rng, 25, 200)
    img = _tgt_noisy(rng, size, base, rng.uniform(0.05, 0.35), rng.uniform(1.0, 3.0))
    seam = _shade(base, 2.4) if rng.random() < 0.5 else (200, 180, 120)
    for x in range(0, size, int(rng.integers(24, 60))):
        cv2.line(img, (x, 0), (x, size), seam, 2)
    for _ in range(int(rng.integers(4, 14))):
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, rng.uniform(15, 40), rng.uniform(15, 40), seam, 2)
    _scatter(
        img,
        rng,
        int(rng.integers(50, 250)),
        2,
        6,
        lambda: _shade(base, float(rng.choice([0.4, 2.2]))),
    )
    return img


def _src_trousers(rng, size: int) -> np.ndarray:
    base = _shade(_vivid(rng), 0.45)
    light = _shade(base, 2.6)
    img = np.full((size, size, 3), base, np.uint8)
    for x in range(0, size, int(rng.integers(24, 48))):  # seams, pockets, patches
        cv2.line(img, (x, 0), (x, size), light, 2)
    for _ in range(12):
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, rng.uniform(15, 40), rng.uniform(15, 40), light, 2)
    _scatter(img, rng, 250, 2, 6, lambda: light if rng.random() < 0.5 else _shade(base, 0.4))
    return img


def _src_skin(rng, size: int) -> np.ndarray:
    tones = [(241, 194, 160), (224, 172, 125), (198, 134, 90), (141, 85, 54), (90, 56, 38)]
    base = tones[int(rng.integers(0, len(tones)))]
    img = np.full((size, size, 3), base, np.uint8)
    # eyes / mouth / ears as dark marks: a face is not a featureless blob
    _scatter(img, rng, 40, 3, 6, lambda: _shade(base, 0.45))
    return img


def _src_hair(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(10, 90, 3))
    img = np.full((size, size, 3), base, np.uint8)
    for _ in range(300):
        x, y = rng.uniform(0, size, 2)
        cv2.line(
            img, (int(x), int(y)), (int(x + rng.uniform(-6, 6)), int(y + 20)), _shade(base, 1.8), 1
        )
    return img


# --------------------------------------------------------------------------- target family
# Kinect-like indoor look: muted colours, noisy materials (plaster, carpet, wood grain, denim),
# photographs instead of flat posters.


def _tgt_wall(rng, size: int) -> np.ndarray:
    base = np.array(_muted(rng, 150, 215), np.float32)
    stains = _periodic_noise(rng, size, 40)
    grain = _periodic_noise(rng, size, 2.5)
    img = base * (1 + 0.10 * stains[..., None] + 0.07 * grain[..., None])
    img = np.clip(img, 0, 255).astype(np.uint8)
    if rng.random() < 0.5:  # block wall: mortar lines
        bh = int(rng.integers(30, 50))
        for row, y in enumerate(range(0, size, bh)):
            cv2.line(img, (0, y), (size, y), _shade(tuple(base.astype(int)), 0.6), 2)
            shift = (row % 2) * bh
            for x in range(shift, size + bh * 2, bh * 2):
                cv2.line(
                    img, (x % size, y), (x % size, y + bh), _shade(tuple(base.astype(int)), 0.6), 2
                )
    for _ in range(rng.integers(6, 11)):  # photographs: colourful multi-scale noise in frames
        w, h = rng.uniform(60, 160, 2)
        x, y = int(rng.uniform(0, size - w)), int(rng.uniform(0, size - h))
        photo = _periodic_noise(rng, 256, rng.uniform(3, 12), 3)[: int(h), : int(w)]
        photo = np.clip(128 + 55 * photo + rng.uniform(-40, 40, 3), 0, 255).astype(np.uint8)
        img[y : y + photo.shape[0], x : x + photo.shape[1]] = photo
        _rect(img, x - 3, y - 3, photo.shape[1] + 5, photo.shape[0] + 5, (35, 30, 25), 4)
    for _ in range(rng.integers(2, 5)):  # whiteboard scribbles / cables
        pts = np.cumsum(rng.normal(0, 14, (12, 2)), axis=0) + rng.uniform(0, size, 2)
        _poly(img, pts, _muted(rng, 20, 90), closed=False, thick=2)
    _scatter(img, rng, size * size // 1400, 3, 9, lambda: _muted(rng, 40, 160))
    return img


def _tgt_floor(rng, size: int) -> np.ndarray:
    if rng.random() < 0.5:  # carpet: coarse + fine coloured noise
        base = np.array(_muted(rng, 60, 140), np.float32)
        n = 0.25 * _periodic_noise(rng, size, 6)[..., None] + 0.2 * _periodic_noise(
            rng, size, 1.5, 3
        )
        img = np.clip(base * (1 + n), 0, 255).astype(np.uint8)
        _scatter(img, rng, size * size // 1800, 3, 8, lambda: _muted(rng, 20, 200))
        return img
    base = np.array(_muted(rng, 90, 170), np.float32) * np.array([1.1, 0.95, 0.75], np.float32)
    img = np.empty((size, size, 3), np.uint8)  # wood planks with grain and dark joints
    plank = size // 16
    grain = _periodic_noise(rng, size, 3)
    for i in range(16):
        tone = base * rng.uniform(0.75, 1.2)
        band = grain[i * plank : (i + 1) * plank]
        img[i * plank : (i + 1) * plank] = np.clip(tone * (1 + 0.18 * band[..., None]), 0, 255)
        for x in rng.uniform(0, size, 2):
            cv2.line(img, (int(x), i * plank), (int(x), (i + 1) * plank), (30, 22, 15), 2)
        cv2.line(img, (0, i * plank), (size, i * plank), (30, 22, 15), 2)
    _scatter(img, rng, size * size // 2500, 2, 6, lambda: _muted(rng, 20, 120))
    return img


def _tgt_ceiling(rng, size: int) -> np.ndarray:
    base = np.array(_muted(rng, 170, 215), np.float32)
    speck = _periodic_noise(rng, size, 1.2)
    img = np.clip(base * (1 + 0.12 * speck[..., None]), 0, 255).astype(np.uint8)
    _scatter(img, rng, size * size // 1000, 2, 4, lambda: _shade(tuple(int(c) for c in base), 0.6))
    panel = size // 8
    for p in range(0, size, panel):
        cv2.line(img, (0, p), (size, p), (90, 90, 90), 3)
        cv2.line(img, (p, 0), (p, size), (90, 90, 90), 3)
    return img


def _tgt_desk(rng, size: int) -> np.ndarray:
    base = np.array(_muted(rng, 90, 170), np.float32) * np.array([1.15, 0.95, 0.7], np.float32)
    grain = _periodic_noise(rng, size, 4)
    grain = cv2.resize(grain, (size, size // 8))  # anisotropic: stretched along x
    grain = np.tile(grain, (8, 1))
    img = np.clip(base * (1 + 0.2 * grain[..., None]), 0, 255).astype(np.uint8)
    for _ in range(rng.integers(8, 16)):
        w, h = rng.uniform(25, 90, 2)
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, w, h, _muted(rng, 120, 240))
        _text(img, x + 3, y + h / 2, 0.3, (40, 40, 40), rng, 5)
    return img


def _tgt_noisy(rng, size: int, base: RGB, amount: float = 0.25, period: float = 2.0):
    n = _periodic_noise(rng, size, period)
    img = np.clip(np.array(base, np.float32) * (1 + amount * n[..., None]), 0, 255)
    return img.astype(np.uint8)


def _tgt_cabinet(rng, size: int) -> np.ndarray:
    base = _muted(rng, 110, 190)
    img = _tgt_noisy(rng, size, base, 0.08, 3)
    for y in range(0, size, size // 4):  # drawers with handles and labels
        _rect(img, 4, y + 4, size - 8, size // 4 - 8, _shade(base, 0.7), 3)
        _rect(img, size // 2 - 30, y + 20, 60, 10, (40, 40, 40))
        _rect(img, 20, y + 14, 50, 24, (235, 235, 220))
        _text(img, 22, y + 32, 0.35, (20, 20, 20), rng, 4)
    return img


def _tgt_screen(rng, size: int) -> np.ndarray:
    img = np.full((size, size, 3), (30, 32, 38), np.uint8)  # dark editor with coloured code
    for line in range(size // 14):
        x = 8 + 16 * int(rng.integers(0, 5))
        for _ in range(rng.integers(1, 5)):
            n = int(rng.integers(2, 8))
            _text(img, x, 12 + 14 * line, 0.38, _muted(rng, 150, 255), rng, n)
            x += n * 9 + 8
    return img


def _tgt_clutter(rng, size: int) -> np.ndarray:
    """Cardboard, binders and printed paper: muted blocks with text and bar codes."""
    img = _tgt_noisy(rng, size, _muted(rng, 120, 190), 0.08, 2)
    for _ in range(40):
        w, h = rng.uniform(30, 140, 2)
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, w, h, _muted(rng, 40, 230))
        _text(img, x + 4, y + h * 0.6, rng.uniform(0.4, 0.8), _muted(rng, 10, 60), rng, 5)
        for k in range(int(rng.integers(0, 12))):
            _rect(img, x + 4 + 3 * k, y + 4, 1, 12, (20, 20, 20))
    return _modulate(img, _periodic_noise(rng, size, 2), 0.06)


def _tgt_shirt(rng, size: int) -> np.ndarray:
    a, b = _contrasting(rng, lambda: _muted(rng, 30, 220))
    if rng.random() < 0.5:  # plaid
        img = np.full((size, size, 3), a, np.uint8)
        step = int(rng.integers(24, 48))
        for p in range(0, size, step):
            _rect(img, p, 0, step // 3, size, b)
            _rect(img, 0, p, size, step // 3, _shade(b, 0.7))
            cv2.line(img, (p + step // 2, 0), (p + step // 2, size), (235, 235, 230), 2)
    else:  # camouflage-like blotches
        n = _periodic_noise(rng, size, rng.uniform(5, 10))
        img = np.where((n > 0.3)[..., None], np.array(a, np.uint8), np.array(b, np.uint8))
        img = np.ascontiguousarray(img.astype(np.uint8))
    _print(img, rng, _contrasting(rng, lambda: _muted(rng, 20, 235)), 150, 3, 7)
    return _modulate(img, _periodic_noise(rng, size, 1.5), 0.12)


def _tgt_trousers(rng, size: int) -> np.ndarray:
    base = (50, 70, 120) if rng.random() < 0.6 else _muted(rng, 30, 110)
    img = _tgt_noisy(rng, size, base, 0.3, 1.2)
    for x in range(0, size, int(rng.integers(30, 60))):
        cv2.line(img, (x, 0), (x, size), (200, 180, 120), 2)
    for _ in range(12):
        x, y = rng.uniform(0, size, 2)
        _rect(img, x, y, rng.uniform(15, 40), rng.uniform(15, 40), (200, 180, 120), 2)
    _scatter(img, rng, 200, 2, 6, lambda: _shade(base, float(rng.choice([0.4, 2.2]))))
    return img


def _tgt_skin(rng, size: int) -> np.ndarray:
    tones = [(230, 190, 165), (205, 160, 125), (180, 125, 95), (125, 85, 60), (85, 60, 45)]
    base = tones[int(rng.integers(0, len(tones)))]
    img = _tgt_noisy(rng, size, base, 0.06, 3)
    _scatter(img, rng, 40, 3, 6, lambda: _shade(base, 0.5))
    return img


def _tgt_hair(rng, size: int) -> np.ndarray:
    return _tgt_noisy(rng, size, tuple(int(c) for c in rng.integers(20, 110, 3)), 0.35, 1.0)


# --------------------------------------------------------------------------- the bank


def _generate(role: Role, family: str, rng: np.random.Generator) -> np.ndarray:
    s = role.size
    kind = role.name.rsplit("_", 1)[0] if role.name[-1].isdigit() else role.name
    if kind.startswith("wall"):
        kind = "wall"
    src = {
        "wall": _src_wall,
        "floor": _src_floor,
        "ceiling": _src_ceiling,
        "desk": _src_desk,
        "desk_frame": lambda r, n: _src_solid_pattern(r, n, (70, 70, 80)),
        "cabinet": _src_cabinet,
        "chair_seat": lambda r, n: _src_solid_pattern(r, n, _vivid(r), 0.6, 300),
        "chair_frame": lambda r, n: _src_solid_pattern(r, n, (45, 45, 50), 1.8),
        "monitor_screen": _src_screen,
        "monitor_body": lambda r, n: _src_solid_pattern(r, n, (25, 25, 28), 2.5, 60),
        "clutter": _src_clutter,
        "shirt": _src_shirt,
        "trousers": _src_trousers,
        "skin": _src_skin,
        "hair": _src_hair,
    }
    tgt = {
        "wall": _tgt_wall,
        "floor": _tgt_floor,
        "ceiling": _tgt_ceiling,
        "desk": _tgt_desk,
        "desk_frame": lambda r, n: _tgt_noisy(r, n, (95, 95, 100), 0.1),
        "cabinet": _tgt_cabinet,
        "chair_seat": lambda r, n: _tgt_noisy(r, n, _muted(r, 30, 110), 0.35, 1.2),
        "chair_frame": lambda r, n: _tgt_noisy(r, n, (60, 60, 62), 0.15),
        "monitor_screen": _tgt_screen,
        "monitor_body": lambda r, n: _tgt_noisy(r, n, (45, 45, 48), 0.1),
        "clutter": _tgt_clutter,
        "shirt": _tgt_shirt,
        "trousers": _tgt_trousers,
        "skin": _tgt_skin,
        "hair": _tgt_hair,
    }
    table = src if family == "source" else tgt
    img = table[kind](rng, s)
    assert img.shape == (s, s, 3) and img.dtype == np.uint8, role.name
    return img


def _pyramid(img: np.ndarray, min_size: int = 4) -> list[np.ndarray]:
    """Mip levels by Gaussian pyrDown with wrap-around borders (textures tile)."""
    levels = [img]
    while levels[-1].shape[0] > min_size:
        cur = levels[-1]
        padded = np.pad(cur, ((4, 4), (4, 4), (0, 0)), mode="wrap")
        levels.append(np.ascontiguousarray(cv2.pyrDown(padded)[2:-2, 2:-2]))
    return levels


class TextureBank:
    """One texture per role of :data:`ROLES`, mip-mapped and packed for vectorised lookups.

    ``images[m]`` is the ``(S, S, 3)`` uint8 RGB texture of material ``m`` (``S`` a power of two).
    """

    def __init__(self, images: list[np.ndarray], texels: list[float]) -> None:
        self.images = images
        pyramids = [_pyramid(img) for img in images]
        self.num_levels = max(len(p) for p in pyramids)
        m = len(images)
        offsets = np.zeros((self.num_levels, m), np.int64)
        shifts = np.zeros((self.num_levels, m), np.int64)  # log2 of the level's size
        chunks, cursor = [], 0
        for j, pyr in enumerate(pyramids):
            for lvl in range(self.num_levels):
                level = pyr[min(lvl, len(pyr) - 1)]
                if lvl < len(pyr):
                    rgba = np.concatenate([level, np.zeros(level.shape[:2] + (1,), np.uint8)], -1)
                    chunks.append(rgba.reshape(-1).view(np.uint32))
                    offsets[lvl, j] = cursor
                    cursor += level.shape[0] * level.shape[1]
                else:  # past the coarsest level: reuse it
                    offsets[lvl, j] = offsets[len(pyr) - 1, j]
                shifts[lvl, j] = int(math.log2(level.shape[0]))
        self.data = np.concatenate(chunks)
        self.offsets = offsets
        self.shifts = shifts
        self.offsets_flat = offsets.reshape(-1).astype(np.int32)
        self.shifts_flat = shifts.reshape(-1).astype(np.int32)
        self.inv_pow2 = np.exp2(-np.arange(self.num_levels, dtype=np.float32))
        self.max_level_int = np.array([len(p) - 1 for p in pyramids], np.int32)
        self.inv_texel = np.array([1.0 / t for t in texels], np.float32)

    def sample(
        self, mat: np.ndarray, u: np.ndarray, v: np.ndarray, footprint: np.ndarray
    ) -> np.ndarray:
        """Filtered colours packed as ``uint32`` (bytes R, G, B, 0), same shape as the inputs.

        ``mat`` material ids; ``u, v`` surface coordinates in metres; ``footprint`` the pixel's
        size on the surface in metres (depth / focal length / cos of incidence). View the result
        with ``.view(np.uint8).reshape(*shape, 4)[..., :3]`` for RGB.

        The mip level is the one whose texels are closest to a pixel; the level is read with
        bilinear weights quantised to 1/16, blended two channels at a time in 32-bit integers.
        """
        m = self.offsets.shape[1]
        inv = self.inv_texel[mat]
        # mip level = round(log2(texels per pixel)), read off the float32 exponent bits of
        # texels-per-pixel times sqrt(2) (cheaper than log2 and rint)
        ratio = footprint * inv * np.float32(math.sqrt(2.0))
        level = (ratio.view(np.int32) >> 23) - np.int32(127)
        level = np.minimum(np.maximum(level, 0), self.max_level_int[mat])
        key = level * np.int32(m) + mat
        shift = self.shifts_flat[key]
        base = self.offsets_flat[key]
        scale = np.ldexp(inv, -level)
        x = u * scale - np.float32(0.5)
        y = v * scale - np.float32(0.5)
        x0 = np.floor(x)
        y0 = np.floor(y)
        wx = ((x - x0) * np.float32(16) + np.float32(0.5)).astype(np.uint32)
        wy = ((y - y0) * np.float32(16) + np.float32(0.5)).astype(np.uint32)
        mask = (np.int32(1) << shift) - np.int32(1)
        ix0 = x0.astype(np.int32) & mask
        iy0 = y0.astype(np.int32) & mask
        ix1 = (ix0 + np.int32(1)) & mask
        row0 = base + (iy0 << shift)
        row1 = base + (((iy0 + np.int32(1)) & mask) << shift)
        data = self.data
        w00 = (np.uint32(16) - wx) * (np.uint32(16) - wy)
        w01 = wx * (np.uint32(16) - wy)
        w10 = (np.uint32(16) - wx) * wy
        w11 = wx * wy
        low = np.uint32(0x00FF00FF)
        acc_lo = np.zeros(u.shape, np.uint32)
        acc_hi = np.zeros(u.shape, np.uint32)
        for index, weight in (
            (row0 + ix0, w00),
            (row0 + ix1, w01),
            (row1 + ix0, w10),
            (row1 + ix1, w11),
        ):
            texel = data[index]
            acc_lo += (texel & low) * weight
            acc_hi += ((texel >> np.uint32(8)) & low) * weight
        half = np.uint32(0x00800080)  # round to nearest
        acc_lo += half
        acc_hi += half
        return ((acc_lo >> np.uint32(8)) & low) | (acc_hi & np.uint32(0xFF00FF00))


@functools.lru_cache(maxsize=6)
def texture_bank(family: str, variant: int = 0) -> TextureBank:
    """The bank of ``family`` (``"source"`` or ``"target"``), variant ``variant`` (cached)."""
    if family not in FAMILIES:
        raise ValueError(f"unknown texture family {family!r}; expected one of {FAMILIES}")
    images = []
    for role in ROLES:
        rng = stream(variant, f"texture/{family}/{role.name}")
        images.append(_generate(role, family, rng))
    return TextureBank(images, [r.texel for r in ROLES])


WARDROBES = ("classic", "varied", "all")
"""People's clothing in the VOC-style source set: ``classic`` = the outfits of the source banks
(saturated stripes, checks and prints: 3 banks x 4 slots); ``varied`` = a new wardrobe every
:data:`WARDROBE_IMAGES` images, drawn from every kind of fabric and colour; ``all`` = a new
wardrobe every :data:`WARDROBE_IMAGES` images whose garments come from every family the world
has (the source prints, the varied fabrics and the target's plaids, blotches and muted cloths),
in rooms of both material families: real photos show people in every kind of clothing, a
superset of what a recording's walkers wear (see :func:`any_garment`)."""
WARDROBE_IMAGES = 20
"""Consecutive VOC images that share one wardrobe of the ``varied`` kind (4 outfits)."""


def any_garment(role: Role, rng: np.random.Generator) -> np.ndarray:
    """A texture for people's role ``role`` drawn from every family of the world.

    Shirts and trousers: the source prints, the varied fabrics or the target's cloths, one
    third each; skin and hair: the source or the target kind, half each. This is the
    distribution of the ``all`` wardrobe *and* of the walkers of ``tum_like`` sequences
    (:func:`walker_bank`), so a source set rendered with it covers what the walkers wear.
    """
    kind = role.name.rsplit("_", 1)[0]
    if kind in ("shirt", "trousers"):
        family = int(rng.integers(0, 3))
        if family == 1:
            return _wardrobe_image(role, rng)
        return _generate(role, "source" if family == 0 else "target", rng)
    return _generate(role, "source" if rng.random() < 0.5 else "target", rng)


ALL_ROOM_BANKS = (("source", 0), ("source", 1), ("source", 2), ("target", 1), ("target", 2),
                  ("target", 3))  # fmt: skip
"""Room materials of the ``all`` wardrobe's images (wardrobe ``w``: ``ALL_ROOM_BANKS[w % 6]``):
the three source banks and three target banks other than the recordings' office (bank 0)."""


@functools.lru_cache(maxsize=8)
def all_wardrobe_bank(room: int, wardrobe: int) -> TextureBank:
    """Room bank ``ALL_ROOM_BANKS[room]`` with the people's materials of ``all``-wardrobe
    ``wardrobe`` (4 outfits drawn by :func:`any_garment`)."""
    family, variant = ALL_ROOM_BANKS[room % len(ALL_ROOM_BANKS)]
    return with_people(
        texture_bank(family, variant),
        lambda _, role: any_garment(role, stream(wardrobe, f"texture/all/{role.name}")),
    )


@functools.lru_cache(maxsize=4)
def walker_bank(family: str, seed: int, preset: str) -> TextureBank:
    """The office's bank of ``family`` (bank 0, the recordings' office for ``target``) with
    people dressed by :func:`any_garment` from a stream of the sequence's own ``seed`` and
    ``preset``: walkers of a sequence wear outfits of the ``all`` wardrobe's distribution that
    no other sequence (and no source image) shows."""
    return with_people(
        texture_bank(family, 0),
        lambda _, role: any_garment(role, stream(seed, f"texture/walkers/{preset}/{role.name}")),
    )


def _wardrobe_image(role: Role, rng: np.random.Generator) -> np.ndarray:
    kind = role.name.rsplit("_", 1)[0]
    if kind == "shirt":
        return _varied_shirt(rng, role.size)
    if kind == "trousers":
        return _varied_trousers(rng, role.size)
    return _generate(role, "source", rng)  # skin tones and hair as in the classic wardrobe


PEOPLE_ROLES = ("shirt_", "trousers_", "skin_", "hair_")
"""Name prefixes of the roles people wear (one of each per outfit slot)."""


def with_people(base: TextureBank, people: Callable[[int, Role], np.ndarray]) -> TextureBank:
    """``base`` with each people's material ``i`` (role ``r``) replaced by ``people(i, r)``."""
    images = [
        people(i, role) if role.name.startswith(PEOPLE_ROLES) else base.images[i]
        for i, role in enumerate(ROLES)
    ]
    return TextureBank(images, [r.texel for r in ROLES])


@functools.lru_cache(maxsize=4)
def wardrobe_bank(variant: int, wardrobe: int) -> TextureBank:
    """Source bank ``variant`` with the people's materials of varied wardrobe ``wardrobe``."""
    return with_people(
        texture_bank("source", variant),
        lambda _, role: _wardrobe_image(role, stream(wardrobe, f"texture/wardrobe/{role.name}")),
    )

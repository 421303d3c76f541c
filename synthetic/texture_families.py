"""The two material families of the synthetic world: ``source`` (saturated prints, the VOC
stand-in) and ``target`` (the recordings' office), one painter per material role, and the varied
wardrobe's garments."""

from __future__ import annotations

import cv2
import numpy as np

from .texture_paint import (
    RGB,
    circle,
    modulate,
    muted,
    periodic_noise,
    poly,
    rect,
    scatter,
    shade,
    text,
    vivid,
)

# --------------------------------------------------------------------------- source family
# Clean and flat: saturated colours, sharp geometric shapes, no noise.


def _src_wall(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(190, 245, 3))
    img = np.full((size, size, 3), base, np.uint8)
    dark = shade(base, 0.55)
    # Wallpaper motif: a dense scatter of medium shapes (5-15 cm) in a darker shade and accents.
    scatter(img, rng, size * size // 900, 4, 12, lambda: dark if rng.random() < 0.6 else vivid(rng))
    # Posters and whiteboards (30-90 cm) with inner geometry and text.
    for _ in range(rng.integers(6, 11)):
        w, h = rng.uniform(50, 150, 2)
        x, y = rng.uniform(0, size - w), rng.uniform(0, size - h)
        rect(img, x, y, w, h, vivid(rng))
        rect(img, x, y, w, h, (20, 20, 20), 2)
        for _ in range(rng.integers(3, 9)):
            cx, cy = x + rng.uniform(0.1, 0.9) * w, y + rng.uniform(0.1, 0.9) * h
            r = rng.uniform(4, min(w, h) / 4)
            if rng.random() < 0.5:
                circle(img, cx, cy, r, vivid(rng))
            else:
                rect(img, cx - r, cy - r, 2 * r, r, vivid(rng))
        text(img, x + 4, y + h - 6, rng.uniform(0.35, 0.7), (15, 15, 15), rng)
    return img


def _src_floor(rng, size: int) -> np.ndarray:
    a = tuple(int(c) for c in rng.integers(120, 220, 3))
    b = shade(a, 0.6)
    img = np.full((size, size, 3), a, np.uint8)
    tile = size // int(rng.choice([8, 16]))
    for ty in range(0, size, tile):
        for tx in range(0, size, tile):
            if ((tx // tile) + (ty // tile)) % 2:
                rect(img, tx, ty, tile - 1, tile - 1, b)
            # an inlay per tile gives corners at every tile, not only at the grout
            r = tile * rng.uniform(0.12, 0.3)
            cx, cy = tx + tile * rng.uniform(0.3, 0.7), ty + tile * rng.uniform(0.3, 0.7)
            circle(img, cx, cy, r, vivid(rng)) if rng.random() < 0.5 else rect(
                img, cx - r, cy - r, 2 * r, 2 * r, vivid(rng)
            )
    for y in range(0, size, tile):
        cv2.line(img, (0, y), (size, y), (40, 40, 40), 2)
        cv2.line(img, (y, 0), (y, size), (40, 40, 40), 2)
    return img


def _src_ceiling(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(215, 250, 3))
    img = np.full((size, size, 3), base, np.uint8)
    panel = size // 10
    scatter(img, rng, size * size // 700, 2, 5, lambda: shade(base, 0.7))
    for p in range(0, size, panel):
        cv2.line(img, (0, p), (size, p), (110, 110, 120), 3)
        cv2.line(img, (p, 0), (p, size), (110, 110, 120), 3)
    for _ in range(6):
        x, y = rng.integers(0, 10, 2) * panel
        rect(img, x + 6, y + 6, panel - 12, panel - 12, (255, 255, 235))
        rect(img, x + 6, y + 6, panel - 12, panel - 12, (90, 90, 90), 2)
    return img


def _src_desk(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(150, 235, 3))
    img = np.full((size, size, 3), base, np.uint8)
    for _ in range(rng.integers(10, 20)):  # papers, notebooks, keyboards
        w, h = rng.uniform(25, 90, 2)
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, w, h, vivid(rng) if rng.random() < 0.5 else (245, 245, 245))
        text(img, x + 3, y + h / 2, 0.3, (20, 20, 20), rng, 5)
    scatter(img, rng, 120, 2, 6, lambda: shade(base, 0.6))
    return img


def _src_solid_pattern(rng, size: int, base: RGB, accent: float = 0.65, count: int = 200):
    img = np.full((size, size, 3), base, np.uint8)
    scatter(img, rng, count, 2, 5, lambda: shade(base, accent))
    return img


def _src_cabinet(rng, size: int) -> np.ndarray:
    img = np.full((size, size, 3), tuple(int(c) for c in rng.integers(100, 200, 3)), np.uint8)
    shelf = size // 4
    for sy in range(0, size, shelf):
        x = 0.0
        while x < size:  # books of random width and colour
            w = rng.uniform(6, 18)
            h = rng.uniform(0.6, 0.92) * shelf
            rect(img, x, sy + shelf - h, w - 1, h, vivid(rng))
            x += w
        cv2.line(img, (0, sy), (size, sy), (30, 30, 30), 4)
    return img


def _src_screen(rng, size: int) -> np.ndarray:
    img = np.full((size, size, 3), vivid(rng), np.uint8)
    for _ in range(rng.integers(4, 8)):  # windows with title bars and text lines
        w, h = rng.uniform(100, 300, 2)
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, w, h, (250, 250, 250))
        rect(img, x, y, w, 14, vivid(rng))
        for line in range(int(h // 16) - 1):
            text(img, x + 6, y + 30 + 16 * line, 0.4, (30, 30, 30), rng, int(rng.integers(4, 14)))
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
    scatter(img, rng, count, rmin, rmax, lambda: colours[int(rng.integers(0, 2))])
    size = img.shape[0]
    for _ in range(size // 48):
        x, y = rng.uniform(0, size - 60, 2)
        text(img, x, y, rng.uniform(0.5, 0.9), colours[int(rng.integers(0, 2))], rng, 4)


def _src_clutter(rng, size: int) -> np.ndarray:
    """Boxes, book covers and packaging: colour blocks with labels, logos and bar codes."""
    img = np.full((size, size, 3), vivid(rng), np.uint8)
    for _ in range(40):
        w, h = rng.uniform(30, 140, 2)
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, w, h, vivid(rng))
        text(img, x + 4, y + h * 0.6, rng.uniform(0.4, 0.8), (15, 15, 15), rng, 5)
        for k in range(int(rng.integers(0, 12))):  # bar code
            rect(img, x + 4 + 3 * k, y + 4, 1, 12, (10, 10, 10))
    scatter(img, rng, 300, 3, 8, lambda: vivid(rng))
    return img


def _src_shirt(rng, size: int) -> np.ndarray:
    a, b = _contrasting(rng, lambda: vivid(rng))
    img = np.full((size, size, 3), a, np.uint8)
    kind = rng.integers(0, 3)
    step = int(rng.integers(16, 32))
    if kind == 0:  # stripes
        for y in range(0, size, step):
            rect(img, 0, y, size, step // 2, b)
    elif kind == 1:  # checks
        for y in range(0, size, step):
            for x in range(0, size, step):
                if (x // step + y // step) % 2:
                    rect(img, x, y, step - 1, step - 1, b)
    _print(img, rng, (a, b) if kind == 2 else _contrasting(rng, lambda: vivid(rng)), 700, 3, 8)
    return img


def _wardrobe_colour(rng) -> RGB:
    """Any clothing colour: saturated or muted, light or dark (the varied wardrobe)."""
    return vivid(rng) if rng.random() < 0.5 else muted(rng, 25, 235)


def varied_shirt(rng, size: int) -> np.ndarray:
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
                rect(img, 0, p, size, step // 2, b)
            else:
                rect(img, p, 0, step // 2, size, b)
    elif kind == 2:  # checks
        for y in range(0, size, step):
            for x in range(0, size, step):
                if (x // step + y // step) % 2:
                    rect(img, x, y, step - 1, step - 1, b)
    elif kind == 3:  # plaid
        for p in range(0, size, step):
            rect(img, p, 0, step // 3, size, b)
            rect(img, 0, p, size, step // 3, shade(b, 0.7))
    elif kind == 4:  # blotches
        n = periodic_noise(rng, size, rng.uniform(4, 12))
        img = np.where((n > rng.uniform(-0.3, 0.5))[..., None], np.array(a, np.uint8),
                       np.array(b, np.uint8)).astype(np.uint8)  # fmt: skip
        img = np.ascontiguousarray(img)
    elif kind == 5:  # print
        _print(img, rng, (a, b), int(rng.integers(100, 700)), 3, 8)
    # kind 0: plain, with the seams and a few marks below
    scatter(
        img, rng, int(rng.integers(20, 200)), 2, 6, lambda: shade(a, float(rng.choice([0.5, 1.6])))
    )
    return modulate(img, periodic_noise(rng, size, rng.uniform(1.0, 3.0)), rng.uniform(0.0, 0.2))


def varied_trousers(rng, size: int) -> np.ndarray:
    """Trousers of the varied wardrobe: dark saturated, denim or muted, with seams."""
    pick = rng.random()
    if pick < 0.35:
        base = shade(vivid(rng), 0.45)
    elif pick < 0.7:
        base = tuple(int(c) for c in np.array((50, 70, 120)) * rng.uniform(0.6, 1.4))
    else:
        base = muted(rng, 25, 200)
    img = _tgt_noisy(rng, size, base, rng.uniform(0.05, 0.35), rng.uniform(1.0, 3.0))
    seam = shade(base, 2.4) if rng.random() < 0.5 else (200, 180, 120)
    for x in range(0, size, int(rng.integers(24, 60))):
        cv2.line(img, (x, 0), (x, size), seam, 2)
    for _ in range(int(rng.integers(4, 14))):
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, rng.uniform(15, 40), rng.uniform(15, 40), seam, 2)
    scatter(
        img,
        rng,
        int(rng.integers(50, 250)),
        2,
        6,
        lambda: shade(base, float(rng.choice([0.4, 2.2]))),
    )
    return img


def _src_trousers(rng, size: int) -> np.ndarray:
    base = shade(vivid(rng), 0.45)
    light = shade(base, 2.6)
    img = np.full((size, size, 3), base, np.uint8)
    for x in range(0, size, int(rng.integers(24, 48))):  # seams, pockets, patches
        cv2.line(img, (x, 0), (x, size), light, 2)
    for _ in range(12):
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, rng.uniform(15, 40), rng.uniform(15, 40), light, 2)
    scatter(img, rng, 250, 2, 6, lambda: light if rng.random() < 0.5 else shade(base, 0.4))
    return img


def _src_skin(rng, size: int) -> np.ndarray:
    tones = [(241, 194, 160), (224, 172, 125), (198, 134, 90), (141, 85, 54), (90, 56, 38)]
    base = tones[int(rng.integers(0, len(tones)))]
    img = np.full((size, size, 3), base, np.uint8)
    # eyes / mouth / ears as dark marks: a face is not a featureless blob
    scatter(img, rng, 40, 3, 6, lambda: shade(base, 0.45))
    return img


def _src_hair(rng, size: int) -> np.ndarray:
    base = tuple(int(c) for c in rng.integers(10, 90, 3))
    img = np.full((size, size, 3), base, np.uint8)
    for _ in range(300):
        x, y = rng.uniform(0, size, 2)
        cv2.line(
            img, (int(x), int(y)), (int(x + rng.uniform(-6, 6)), int(y + 20)), shade(base, 1.8), 1
        )
    return img


# --------------------------------------------------------------------------- target family
# Kinect-like indoor look: muted colours, noisy materials (plaster, carpet, wood grain, denim),
# photographs instead of flat posters.


def _tgt_wall(rng, size: int) -> np.ndarray:
    base = np.array(muted(rng, 150, 215), np.float32)
    stains = periodic_noise(rng, size, 40)
    grain = periodic_noise(rng, size, 2.5)
    img = base * (1 + 0.10 * stains[..., None] + 0.07 * grain[..., None])
    img = np.clip(img, 0, 255).astype(np.uint8)
    if rng.random() < 0.5:  # block wall: mortar lines
        bh = int(rng.integers(30, 50))
        for row, y in enumerate(range(0, size, bh)):
            cv2.line(img, (0, y), (size, y), shade(tuple(base.astype(int)), 0.6), 2)
            shift = (row % 2) * bh
            for x in range(shift, size + bh * 2, bh * 2):
                cv2.line(
                    img, (x % size, y), (x % size, y + bh), shade(tuple(base.astype(int)), 0.6), 2
                )
    for _ in range(rng.integers(6, 11)):  # photographs: colourful multi-scale noise in frames
        w, h = rng.uniform(60, 160, 2)
        x, y = int(rng.uniform(0, size - w)), int(rng.uniform(0, size - h))
        photo = periodic_noise(rng, 256, rng.uniform(3, 12), 3)[: int(h), : int(w)]
        photo = np.clip(128 + 55 * photo + rng.uniform(-40, 40, 3), 0, 255).astype(np.uint8)
        img[y : y + photo.shape[0], x : x + photo.shape[1]] = photo
        rect(img, x - 3, y - 3, photo.shape[1] + 5, photo.shape[0] + 5, (35, 30, 25), 4)
    for _ in range(rng.integers(2, 5)):  # whiteboard scribbles / cables
        pts = np.cumsum(rng.normal(0, 14, (12, 2)), axis=0) + rng.uniform(0, size, 2)
        poly(img, pts, muted(rng, 20, 90), closed=False, thick=2)
    scatter(img, rng, size * size // 1400, 3, 9, lambda: muted(rng, 40, 160))
    return img


def _tgt_floor(rng, size: int) -> np.ndarray:
    if rng.random() < 0.5:  # carpet: coarse + fine coloured noise
        base = np.array(muted(rng, 60, 140), np.float32)
        n = 0.25 * periodic_noise(rng, size, 6)[..., None] + 0.2 * periodic_noise(rng, size, 1.5, 3)
        img = np.clip(base * (1 + n), 0, 255).astype(np.uint8)
        scatter(img, rng, size * size // 1800, 3, 8, lambda: muted(rng, 20, 200))
        return img
    base = np.array(muted(rng, 90, 170), np.float32) * np.array([1.1, 0.95, 0.75], np.float32)
    img = np.empty((size, size, 3), np.uint8)  # wood planks with grain and dark joints
    plank = size // 16
    grain = periodic_noise(rng, size, 3)
    for i in range(16):
        tone = base * rng.uniform(0.75, 1.2)
        band = grain[i * plank : (i + 1) * plank]
        img[i * plank : (i + 1) * plank] = np.clip(tone * (1 + 0.18 * band[..., None]), 0, 255)
        for x in rng.uniform(0, size, 2):
            cv2.line(img, (int(x), i * plank), (int(x), (i + 1) * plank), (30, 22, 15), 2)
        cv2.line(img, (0, i * plank), (size, i * plank), (30, 22, 15), 2)
    scatter(img, rng, size * size // 2500, 2, 6, lambda: muted(rng, 20, 120))
    return img


def _tgt_ceiling(rng, size: int) -> np.ndarray:
    base = np.array(muted(rng, 170, 215), np.float32)
    speck = periodic_noise(rng, size, 1.2)
    img = np.clip(base * (1 + 0.12 * speck[..., None]), 0, 255).astype(np.uint8)
    scatter(img, rng, size * size // 1000, 2, 4, lambda: shade(tuple(int(c) for c in base), 0.6))
    panel = size // 8
    for p in range(0, size, panel):
        cv2.line(img, (0, p), (size, p), (90, 90, 90), 3)
        cv2.line(img, (p, 0), (p, size), (90, 90, 90), 3)
    return img


def _tgt_desk(rng, size: int) -> np.ndarray:
    base = np.array(muted(rng, 90, 170), np.float32) * np.array([1.15, 0.95, 0.7], np.float32)
    grain = periodic_noise(rng, size, 4)
    grain = cv2.resize(grain, (size, size // 8))  # anisotropic: stretched along x
    grain = np.tile(grain, (8, 1))
    img = np.clip(base * (1 + 0.2 * grain[..., None]), 0, 255).astype(np.uint8)
    for _ in range(rng.integers(8, 16)):
        w, h = rng.uniform(25, 90, 2)
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, w, h, muted(rng, 120, 240))
        text(img, x + 3, y + h / 2, 0.3, (40, 40, 40), rng, 5)
    return img


def _tgt_noisy(rng, size: int, base: RGB, amount: float = 0.25, period: float = 2.0):
    n = periodic_noise(rng, size, period)
    img = np.clip(np.array(base, np.float32) * (1 + amount * n[..., None]), 0, 255)
    return img.astype(np.uint8)


def _tgt_cabinet(rng, size: int) -> np.ndarray:
    base = muted(rng, 110, 190)
    img = _tgt_noisy(rng, size, base, 0.08, 3)
    for y in range(0, size, size // 4):  # drawers with handles and labels
        rect(img, 4, y + 4, size - 8, size // 4 - 8, shade(base, 0.7), 3)
        rect(img, size // 2 - 30, y + 20, 60, 10, (40, 40, 40))
        rect(img, 20, y + 14, 50, 24, (235, 235, 220))
        text(img, 22, y + 32, 0.35, (20, 20, 20), rng, 4)
    return img


def _tgt_screen(rng, size: int) -> np.ndarray:
    img = np.full((size, size, 3), (30, 32, 38), np.uint8)  # dark editor with coloured code
    for line in range(size // 14):
        x = 8 + 16 * int(rng.integers(0, 5))
        for _ in range(rng.integers(1, 5)):
            n = int(rng.integers(2, 8))
            text(img, x, 12 + 14 * line, 0.38, muted(rng, 150, 255), rng, n)
            x += n * 9 + 8
    return img


def _tgt_clutter(rng, size: int) -> np.ndarray:
    """Cardboard, binders and printed paper: muted blocks with text and bar codes."""
    img = _tgt_noisy(rng, size, muted(rng, 120, 190), 0.08, 2)
    for _ in range(40):
        w, h = rng.uniform(30, 140, 2)
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, w, h, muted(rng, 40, 230))
        text(img, x + 4, y + h * 0.6, rng.uniform(0.4, 0.8), muted(rng, 10, 60), rng, 5)
        for k in range(int(rng.integers(0, 12))):
            rect(img, x + 4 + 3 * k, y + 4, 1, 12, (20, 20, 20))
    return modulate(img, periodic_noise(rng, size, 2), 0.06)


def _tgt_shirt(rng, size: int) -> np.ndarray:
    a, b = _contrasting(rng, lambda: muted(rng, 30, 220))
    if rng.random() < 0.5:  # plaid
        img = np.full((size, size, 3), a, np.uint8)
        step = int(rng.integers(24, 48))
        for p in range(0, size, step):
            rect(img, p, 0, step // 3, size, b)
            rect(img, 0, p, size, step // 3, shade(b, 0.7))
            cv2.line(img, (p + step // 2, 0), (p + step // 2, size), (235, 235, 230), 2)
    else:  # camouflage-like blotches
        n = periodic_noise(rng, size, rng.uniform(5, 10))
        img = np.where((n > 0.3)[..., None], np.array(a, np.uint8), np.array(b, np.uint8))
        img = np.ascontiguousarray(img.astype(np.uint8))
    _print(img, rng, _contrasting(rng, lambda: muted(rng, 20, 235)), 150, 3, 7)
    return modulate(img, periodic_noise(rng, size, 1.5), 0.12)


def _tgt_trousers(rng, size: int) -> np.ndarray:
    base = (50, 70, 120) if rng.random() < 0.6 else muted(rng, 30, 110)
    img = _tgt_noisy(rng, size, base, 0.3, 1.2)
    for x in range(0, size, int(rng.integers(30, 60))):
        cv2.line(img, (x, 0), (x, size), (200, 180, 120), 2)
    for _ in range(12):
        x, y = rng.uniform(0, size, 2)
        rect(img, x, y, rng.uniform(15, 40), rng.uniform(15, 40), (200, 180, 120), 2)
    scatter(img, rng, 200, 2, 6, lambda: shade(base, float(rng.choice([0.4, 2.2]))))
    return img


def _tgt_skin(rng, size: int) -> np.ndarray:
    tones = [(230, 190, 165), (205, 160, 125), (180, 125, 95), (125, 85, 60), (85, 60, 45)]
    base = tones[int(rng.integers(0, len(tones)))]
    img = _tgt_noisy(rng, size, base, 0.06, 3)
    scatter(img, rng, 40, 3, 6, lambda: shade(base, 0.5))
    return img


def _tgt_hair(rng, size: int) -> np.ndarray:
    return _tgt_noisy(rng, size, tuple(int(c) for c in rng.integers(20, 110, 3)), 0.35, 1.0)


def paint_material(name: str, size: int, family: str, rng: np.random.Generator) -> np.ndarray:
    """The ``(size, size, 3)`` uint8 RGB texture of material role ``name`` in ``family``
    (``source`` or ``target``), drawn from ``rng``."""
    s = size
    kind = name.rsplit("_", 1)[0] if name[-1].isdigit() else name
    if kind.startswith("wall"):
        kind = "wall"
    src = {
        "wall": _src_wall,
        "floor": _src_floor,
        "ceiling": _src_ceiling,
        "desk": _src_desk,
        "desk_frame": lambda r, n: _src_solid_pattern(r, n, (70, 70, 80)),
        "cabinet": _src_cabinet,
        "chair_seat": lambda r, n: _src_solid_pattern(r, n, vivid(r), 0.6, 300),
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
        "chair_seat": lambda r, n: _tgt_noisy(r, n, muted(r, 30, 110), 0.35, 1.2),
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
    assert img.shape == (s, s, 3) and img.dtype == np.uint8, name
    return img

"""Procedural, mip-mapped surface textures in two families (``source`` and ``target``).

A :class:`TextureBank` holds one texture per material *role* (walls, floor, desk, shirts, ...)
and samples it per pixel. Sampling is filtered: the mip level is chosen from the pixel's
footprint on the surface (metres per pixel over metres per texel), and the level is read with
bilinear interpolation, so a static surface looks the same from nearby viewpoints instead of
shimmering (ORB matching between frames depends on that).

All levels of all materials are packed into one flat ``uint32`` array (RGBA bytes) so that a
texture lookup for every pixel of a frame is a handful of vectorised integer gathers. The painters
of each family are in :mod:`.texture_families` (drawing helpers: :mod:`.texture_paint`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from .seeding import stream
from .texture_families import paint_material, varied_shirt, varied_trousers

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


# --------------------------------------------------------------------------- the bank


def _generate(role: Role, family: str, rng: np.random.Generator) -> np.ndarray:
    return paint_material(role.name, role.size, family, rng)


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
        return varied_shirt(rng, role.size)
    if kind == "trousers":
        return varied_trousers(rng, role.size)
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

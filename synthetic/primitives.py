"""Solid primitives (oriented boxes, capped cylinders, ellipsoids) and their ray intersections.

Each primitive has a local frame (``rot`` maps local to world axes, ``center`` in world metres)
and ``half`` extents in that frame: a box's half sizes, a cylinder's ``(r, r, half length)``
along local z, an ellipsoid's three radii. Rays are ``o + t d`` with one origin and many
directions; with camera-space directions scaled to unit z, ``t`` is the depth along the optical
axis.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

BOX, CYLINDER, ELLIPSOID = 0, 1, 2
NEAR = 0.05
"""Closest accepted hit along a ray (metres of depth)."""

_CORNERS = np.array(
    [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float32
)


@dataclass(frozen=True)
class Prim:
    """One primitive of a scene: geometry plus class label, material and colour tint."""

    kind: int
    center: tuple[float, float, float]
    rot: np.ndarray
    half: tuple[float, float, float]
    label: int
    material: int
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class PrimArrays:
    """Primitives stacked into arrays (P = count): the renderer's input."""

    kind: np.ndarray  # (P,) int8
    center: np.ndarray  # (P, 3) float32
    rot: np.ndarray  # (P, 3, 3) float32, local -> world
    half: np.ndarray  # (P, 3) float32
    label: np.ndarray  # (P,) uint8
    material: np.ndarray  # (P,) int32
    tint: np.ndarray  # (P, 3) float32

    def __len__(self) -> int:
        return len(self.kind)

    @staticmethod
    def stack(prims: Sequence[Prim]) -> PrimArrays:
        if not prims:
            return PrimArrays(
                np.zeros(0, np.int8),
                np.zeros((0, 3), np.float32),
                np.zeros((0, 3, 3), np.float32),
                np.zeros((0, 3), np.float32),
                np.zeros(0, np.uint8),
                np.zeros(0, np.int32),
                np.zeros((0, 3), np.float32),
            )
        return PrimArrays(
            np.array([p.kind for p in prims], np.int8),
            np.array([p.center for p in prims], np.float32),
            np.array([p.rot for p in prims], np.float32),
            np.array([p.half for p in prims], np.float32),
            np.array([p.label for p in prims], np.uint8),
            np.array([p.material for p in prims], np.int32),
            np.array([p.tint for p in prims], np.float32),
        )

    def concat(self, other: PrimArrays) -> PrimArrays:
        return PrimArrays(
            *(np.concatenate([a, b]) for a, b in zip(self.astuple(), other.astuple(), strict=True))
        )

    def astuple(self) -> tuple[np.ndarray, ...]:
        return (self.kind, self.center, self.rot, self.half, self.label, self.material, self.tint)

    def corners(self) -> np.ndarray:
        """World coordinates ``(P, 8, 3)`` of each primitive's local bounding box corners."""
        local = _CORNERS[None] * self.half[:, None, :]
        return np.einsum("pij,pkj->pki", self.rot, local) + self.center[:, None, :]


# --------------------------------------------------------------------------- frames


def frame_from_axis(axis) -> np.ndarray:
    """A rotation whose local z is ``axis`` (any length > 0); x and y complete it."""
    # plain floats: this runs for every limb of every person in every frame
    ax, ay, az = (float(c) for c in axis)
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    zx, zy, zz = ax / norm, ay / norm, az / norm
    if abs(zx) < 0.9:  # x = (1, 0, 0) x z
        xx, xy, xz = 0.0, -zz, zy
    else:  # x = (0, 1, 0) x z
        xx, xy, xz = zz, 0.0, -zx
    n = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / n, xy / n, xz / n
    yx, yy, yz = zy * xz - zz * xy, zz * xx - zx * xz, zx * xy - zy * xx
    return np.array([[xx, yx, zx], [xy, yy, zy], [xz, yz, zz]])


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def box(center, size, label: int, material: int, rot=None, tint=(1.0, 1.0, 1.0)) -> Prim:
    """An oriented box of full ``size`` (x, y, z) metres."""
    r = np.eye(3) if rot is None else np.asarray(rot)
    half = tuple(float(s) / 2 for s in size)
    return Prim(BOX, tuple(map(float, center)), r, half, label, material, tint)


def cylinder(p0, p1, radius: float, label: int, material: int, tint=(1.0, 1.0, 1.0)) -> Prim:
    """A capped cylinder from point ``p0`` to ``p1``."""
    ax, ay, az = (float(b) - float(a) for a, b in zip(p0, p1, strict=True))
    length = math.sqrt(ax * ax + ay * ay + az * az)
    rot = frame_from_axis((ax, ay, az) if length > 1e-9 else (0.0, 0.0, 1.0))
    center = tuple((float(a) + float(b)) / 2 for a, b in zip(p0, p1, strict=True))
    return Prim(CYLINDER, center, rot, (radius, radius, length / 2), label, material, tint)


def ellipsoid(center, radii, label: int, material: int, rot=None, tint=(1.0, 1.0, 1.0)) -> Prim:
    r = np.eye(3) if rot is None else np.asarray(rot)
    return Prim(
        ELLIPSOID, tuple(map(float, center)), r, tuple(map(float, radii)), label, material, tint
    )


# --------------------------------------------------------------------------- intersections
# Inputs: ``o`` (3,) the ray origin and ``d`` three arrays (any equal shape) holding the direction
# components, both in the primitive's local frame (origin relative to its centre).
# Output: ``t`` (same shape) float32, +inf where the ray misses.

Components = tuple[np.ndarray, np.ndarray, np.ndarray]


def hit_box(o: np.ndarray, d: Components, half: np.ndarray) -> np.ndarray:
    t_near = t_far = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for a in range(3):
            inv = np.float32(1.0) / d[a]
            t1 = (np.float32(-half[a] - o[a])) * inv
            t2 = (np.float32(half[a] - o[a])) * inv
            lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
            t_near = lo if t_near is None else np.maximum(t_near, lo)
            t_far = hi if t_far is None else np.minimum(t_far, hi)
    ok = (t_near <= t_far) & (t_near > NEAR)
    return np.where(ok, t_near, np.float32(np.inf))


def hit_cylinder(o: np.ndarray, d: Components, half: np.ndarray) -> np.ndarray:
    r, hz = float(half[0]), float(half[2])
    dx, dy, dz = d
    ox, oy, oz = (np.float32(v) for v in o)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = dx * dx + dy * dy
        b = np.float32(2) * (ox * dx + oy * dy)
        c = np.float32(ox * ox + oy * oy - r * r)
        disc = b * b - np.float32(4) * a * c
        t_side = (-b - np.sqrt(np.maximum(disc, 0))) / (np.float32(2) * a)
        z = oz + t_side * dz
        side_ok = (disc >= 0) & (np.abs(z) <= hz) & (t_side > NEAR)
        t = np.where(side_ok, t_side, np.float32(np.inf))
        if abs(oz) > hz:  # the cap facing the origin (the far one is always hidden)
            cap_z = np.float32(hz if oz > 0 else -hz)
            t_cap = (cap_z - oz) / dz
            cx = ox + t_cap * dx
            cy = oy + t_cap * dy
            cap_ok = (cx * cx + cy * cy <= r * r) & (t_cap > NEAR) & (t_cap < t)
            t = np.where(cap_ok, t_cap, t)
    return t


def hit_ellipsoid(o: np.ndarray, d: Components, half: np.ndarray) -> np.ndarray:
    inv = (1.0 / np.asarray(half, np.float64)).astype(np.float32)
    os_ = (np.asarray(o, np.float64) / half).astype(np.float32)
    dx, dy, dz = d[0] * inv[0], d[1] * inv[1], d[2] * inv[2]
    a = dx * dx + dy * dy + dz * dz
    b = np.float32(2) * (os_[0] * dx + os_[1] * dy + os_[2] * dz)
    c = np.float32(os_ @ os_ - 1.0)
    disc = b * b - np.float32(4) * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (np.float32(2) * a)
    ok = (disc >= 0) & (t > NEAR)
    return np.where(ok, t, np.float32(np.inf))


HIT = {BOX: hit_box, CYLINDER: hit_cylinder, ELLIPSOID: hit_ellipsoid}


def surface(
    kind: int, p: Components, half: Components
) -> tuple[Components, np.ndarray, np.ndarray]:
    """Local normals and texture coordinates ``u, v`` (metres) of surface points.

    ``p`` three (n,) arrays: hit points of primitives of ``kind`` in their local frames;
    ``half`` their half extents, three (n,) arrays. Boxes map each face's two in-plane axes; cylinders and ellipsoids wrap the
    angle around local z (so a texture runs around limbs and heads), z being the second axis.
    """
    hx, hy, hz = half
    x, y, z = p
    if kind == BOX:
        ax, ay, az = np.abs(x) / hx, np.abs(y) / hy, np.abs(z) / hz
        on_x = (ax >= ay) & (ax >= az)
        on_z = ~on_x & (az > ay)
        on_y = ~(on_x | on_z)
        n = (np.sign(x) * on_x, np.sign(y) * on_y, np.sign(z) * on_z)
        # the two in-face coordinates: (y, z) on x faces, (x, z) on y faces, (x, y) on z faces
        u = np.where(on_x, y + hy, x + hx)
        v = np.where(on_z, hy - y, hz - z)
        return n, u, v
    ang = np.arctan2(y, x) + np.float32(np.pi)
    if kind == CYLINDER:
        radial = np.sqrt(x * x + y * y)
        cap = np.abs(np.abs(z) - hz) < np.abs(radial - hx)
        side = (~cap) / np.maximum(radial, np.float32(1e-6))
        n = (x * side, y * side, np.sign(z) * cap)
        u = np.where(cap, x, ang * hx)
        v = np.where(cap, y, hz - z)
        return n, u, v
    gx, gy, gz = x / (hx * hx), y / (hy * hy), z / (hz * hz)
    inv = np.float32(1) / np.sqrt(gx * gx + gy * gy + gz * gz)
    return (gx * inv, gy * inv, gz * inv), ang * (np.float32(0.5) * (hx + hy)), hz - z

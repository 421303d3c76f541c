"""The ray caster: a room (inside of an axis-aligned box) plus solid primitives.

Per frame: the world ray directions are outer sums of two short vectors (camera rays are
``(x, y, 1)``), the room is hit analytically at every pixel, then each primitive is tested only
inside its projected screen-space bounding box, keeping the nearest hit per pixel (a z-buffer of
ray parameters, which are depths along the optical axis because camera rays have unit z). A
second pass computes normals and texture coordinates of the visible surfaces only, then the
filtered texture colour and a view-independent Lambertian shading (so a static surface has the
same colour from every viewpoint). Everything is float32, component-wise ``(H, W)`` arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from uss_slam.core.tum_io import CameraIntrinsics

from .primitives import HIT, NEAR, PrimArrays, surface
from .textures import TextureBank

ROOM_FACES = 6
"""Ids 0..5 of the id buffer are the room faces x-, x+, y-, y+, floor, ceiling."""
_CHUNK = 16384
"""Pixels per chunk of the vectorised per-pixel passes (keeps temporaries in cache)."""

# Per room face (x-, x+, y-, y+, floor, ceiling): the inward normal and texture axes. On walls u
# runs to the viewer's right and v downwards from the ceiling, so texture images stand upright.
_FACE_NORMAL = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float32
)
_FACE_NORMAL = tuple(np.ascontiguousarray(c) for c in _FACE_NORMAL.T)
_FACE_U_X = np.array([0, 0, -1, 1, 1, 1], np.float32)  # u = U_X x + U_Y y
_FACE_U_Y = np.array([1, -1, 0, 0, 0, 0], np.float32)
_FACE_V_Y = np.array([0, 0, 0, 0, 1, 1], np.float32)  # v = y on floor / ceiling
_FACE_IS_WALL = np.array([1, 1, 1, 1, 0, 0], np.float32)  # v = ceiling height - z on walls


_EDGES = np.array(  # the 12 edges of a box as pairs of corner indices (see primitives._CORNERS)
    [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]]
)


@dataclass(frozen=True)
class PointLight:
    position: tuple[float, float, float]
    intensity: float
    falloff: float  # metres at which the light has dropped to half


@dataclass(frozen=True)
class Lighting:
    """View-independent shading: ``ambient + hemi * (1 + n_z) / 2 + sum of Lambertian lights``."""

    ambient: float = 0.55
    hemi: float = 0.25
    lights: tuple[PointLight, ...] = ()
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Room:
    """The room box in world metres (z up, floor at ``lo[2]``) and its six face materials."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    materials: tuple[int, int, int, int, int, int]


@dataclass
class RenderResult:
    """One rendered view, ``H × W``. Depth is exact (no sensor model)."""

    rgb: np.ndarray  # (H, W, 3) float32 RGB in [0, 1], before any style effects
    depth: np.ndarray  # (H, W) float32 metres along the optical axis
    labels: np.ndarray  # (H, W) uint8 class ids
    ids: np.ndarray  # (H, W) int32 primitive id (0..5 room faces, 6 + k primitive k)


class Renderer:
    """Renders views of a camera with the given pinhole intrinsics (distortion ignored).

    ``cull=False`` tests every primitive against every pixel, in the given order (the naive
    caster; same images, used as the speed reference in ``benchmarks/synth_speed.py``).
    """

    def __init__(self, camera: CameraIntrinsics, cull: bool = True) -> None:
        self.camera = camera
        self.cull = cull
        w, h = camera.width, camera.height
        self.xs = ((np.arange(w) - camera.cx) / camera.fx).astype(np.float64)
        self.ys = ((np.arange(h) - camera.cy) / camera.fy).astype(np.float64)
        self.xs32, self.ys32 = self.xs.astype(np.float32), self.ys.astype(np.float32)
        self.ray_norm = np.sqrt(
            np.add.outer(self.ys**2 + 1.0, self.xs**2).astype(np.float32)
        )  # |(x, y, 1)| per pixel
        self.inv_ray_norm = np.float32(1) / self.ray_norm
        self.focal = np.float32(0.5 * (camera.fx + camera.fy))
        step = max(4, 32768 // w)
        self._strips = [(y, min(y + step, h)) for y in range(0, h, step)]
        # surface buffers reused from frame to frame: u, v, nx, ny, nz (float32), material
        self._buffers = [np.empty((h, w), np.float32) for _ in range(5)] + [
            np.empty((h, w), np.int32)
        ]

    def directions(self, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World ray directions ``R (x, y, 1)`` per pixel: three ``(H, W)`` float32 arrays."""
        return tuple(  # type: ignore[return-value]
            np.add.outer(rot[i, 1] * self.ys + rot[i, 2], rot[i, 0] * self.xs).astype(np.float32)
            for i in range(3)
        )

    def render(
        self,
        pose: np.ndarray,
        room: Room,
        prims: PrimArrays,
        bank: TextureBank,
        lighting: Lighting,
    ) -> RenderResult:
        """Render from the camera-to-world ``pose`` (4×4, optical frame: x right, y down, z ahead)."""
        h, w = self.camera.height, self.camera.width
        rot = np.asarray(pose[:3, :3], np.float64)
        origin = np.asarray(pose[:3, 3], np.float64)
        o32 = origin.astype(np.float32)
        d = self.directions(rot)
        zbuf = np.empty((h, w), np.float32)
        face = np.empty((h, w), np.uint8)
        u, v, nx, ny, nz, mat = self._buffers
        materials = np.asarray(room.materials, np.int32)

        # --- room: every pixel, in strips of rows so that temporaries stay in cache
        for y0, y1 in self._strips:
            rows = slice(y0, y1)
            zb, f = self._room(room, origin, [c[rows] for c in d])
            zbuf[rows], face[rows] = zb, f
            pts = [o32[i] + zb * d[i][rows] for i in range(3)]
            u[rows] = _FACE_U_X[f] * pts[0] + _FACE_U_Y[f] * pts[1]
            v[rows] = _FACE_V_Y[f] * pts[1] - _FACE_IS_WALL[f] * (pts[2] - np.float32(room.hi[2]))
            nx[rows] = _FACE_NORMAL[0][f]
            ny[rows] = _FACE_NORMAL[1][f]
            nz[rows] = _FACE_NORMAL[2][f]
            mat[rows] = materials[f]
        ids = face.astype(np.int32)

        # --- primitives, front to back, each inside its projected bounding box
        if len(prims):
            rects, near = self._screen_rects(prims, pose)
            visible = np.flatnonzero(rects[:, 0] >= 0)
            order = visible[np.argsort(near[visible], kind="stable")]
            if not self.cull:
                rects[:] = (0, 0, w, h)
                near[:] = 0.0
                order = np.arange(len(prims))
            for k in order:
                x0, y0, x1, y1 = (int(c) for c in rects[k])
                zb = zbuf[y0:y1, x0:x1]
                if near[k] >= zb.max():
                    continue  # entirely behind what is already drawn
                r = prims.rot[k].astype(np.float64)
                m = r.T @ rot  # camera ray (x, y, 1) -> direction in the primitive's frame
                m = m.astype(np.float32)
                d_l = tuple(
                    np.add.outer(m[j, 1] * self.ys32[y0:y1] + m[j, 2], m[j, 0] * self.xs32[x0:x1])
                    for j in range(3)
                )
                t = HIT[int(prims.kind[k])]((origin - prims.center[k]) @ r, d_l, prims.half[k])
                closer = t < zb
                zb[closer] = t[closer]
                ids[y0:y1, x0:x1][closer] = ROOM_FACES + k
            self._object_surfaces(prims, ids, zbuf, d, o32)

        labels = np.concatenate([np.zeros(ROOM_FACES, np.uint8), prims.label])[ids]

        # --- colour: filtered texture times shading and per-object tint
        tint = np.concatenate([np.ones((ROOM_FACES, 3), np.float32), prims.tint])
        tint *= np.asarray(lighting.color, np.float32) / np.float32(255)
        tint = [np.ascontiguousarray(tint[:, c]) for c in range(3)]
        rgb = np.empty((h, w, 3), np.float32)
        for y0, y1 in self._strips:
            rows = slice(y0, y1)
            dd = [c[rows] for c in d]
            z = zbuf[rows]
            cos = np.abs(nx[rows] * dd[0] + ny[rows] * dd[1] + nz[rows] * dd[2])
            cos *= self.inv_ray_norm[rows]
            footprint = z * self.ray_norm[rows] / (self.focal * np.maximum(cos, np.float32(0.15)))
            packed = bank.sample(mat[rows], u[rows], v[rows], footprint)
            pts = [o32[i] + z * dd[i] for i in range(3)]
            shade = self._shade(pts, (nx[rows], ny[rows], nz[rows]), lighting)
            albedo = packed.view(np.uint8).reshape(y1 - y0, w, 4).astype(np.float32)
            strip_ids = ids[rows]
            for c in range(3):
                np.multiply(albedo[..., c], tint[c][strip_ids] * shade, out=rgb[rows, :, c])
        return RenderResult(rgb=rgb, depth=zbuf, labels=labels, ids=ids)

    def _object_surfaces(self, prims: PrimArrays, ids, zbuf, d, o32) -> None:
        """Normals, texture coordinates and materials of all pixels showing a primitive.

        Vectorised over those pixels (in cache-sized chunks) with per-pixel primitive parameters
        gathered from small tables: cheaper than a pass per primitive, whose cost would be
        dominated by per-call overhead.
        """
        obj_all = np.flatnonzero(ids.reshape(-1) >= ROOM_FACES)
        if len(obj_all) == 0:
            return
        # one row per parameter: rotation entries r_ij (local -> world), centre, half extents
        table = np.concatenate(
            [prims.rot.reshape(-1, 9).T, prims.center.T, prims.half.T], axis=0
        ).astype(np.float32)
        table = np.ascontiguousarray(table)
        u, v, nx, ny, nz, mat = (b.reshape(-1) for b in self._buffers)
        flat_ids, flat_z = ids.reshape(-1), zbuf.reshape(-1)
        flat_d = [c.reshape(-1) for c in d]
        for start in range(0, len(obj_all), _CHUNK):
            obj = obj_all[start : start + _CHUNK]
            k = flat_ids[obj] - ROOM_FACES
            t = flat_z[obj]
            params = np.take(table, k, axis=1)
            r = params[:9]  # r[3 * i + j] = R[i, j]
            rel = [o32[i] + t * flat_d[i][obj] - params[9 + i] for i in range(3)]
            p_l = [r[j] * rel[0] + r[3 + j] * rel[1] + r[6 + j] * rel[2] for j in range(3)]
            half = params[12:15]
            kinds = np.take(prims.kind, k)
            present = np.flatnonzero(np.bincount(kinds, minlength=3))
            if len(present) == 1:
                n_l, u[obj], v[obj] = surface(int(present[0]), tuple(p_l), tuple(half))
            else:
                n_l = [np.empty(len(obj), np.float32) for _ in range(3)]
                uo = np.empty(len(obj), np.float32)
                vo = np.empty(len(obj), np.float32)
                for kind in present:
                    sel = np.flatnonzero(kinds == kind)
                    n_k, uo[sel], vo[sel] = surface(
                        int(kind), tuple(c[sel] for c in p_l), tuple(c[sel] for c in half)
                    )
                    for j in range(3):
                        n_l[j][sel] = n_k[j]
                u[obj], v[obj] = uo, vo
            for i, buf in enumerate((nx, ny, nz)):
                buf[obj] = r[3 * i] * n_l[0] + r[3 * i + 1] * n_l[1] + r[3 * i + 2] * n_l[2]
            mat[obj] = np.take(prims.material, k)

    @staticmethod
    def _room(room: Room, origin: np.ndarray, d: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Depth and face id (0..5) of the room wall each ray of ``d`` hits first."""
        t_axis, positive = [], []
        with np.errstate(divide="ignore"):
            for a in range(3):
                inv = np.float32(1) / d[a]  # ±inf for a zero component: never the nearest
                pos = inv > 0
                hi = np.float32(room.hi[a] - origin[a])
                lo = np.float32(room.lo[a] - origin[a])
                t_axis.append(np.where(pos, hi, lo) * inv)
                positive.append(pos.view(np.uint8))
        tx, ty, tz = t_axis
        on_x = (tx <= ty) & (tx <= tz)
        on_y = ~on_x & (ty <= tz)
        on_z = ~(on_x | on_y)
        face = on_x * positive[0] + on_y * (2 + positive[1]) + on_z * (4 + positive[2])
        return np.minimum(np.minimum(tx, ty), tz), face.astype(np.uint8)

    def flow(
        self, depth: np.ndarray, pose: np.ndarray, other: np.ndarray, step: int = 4
    ) -> np.ndarray:
        """Image motion ``(H, W, 2)`` pixels of the static scene from ``pose`` to ``other``.

        ``depth`` (H, W) metres seen from camera-to-world ``pose``; the result is where each
        pixel's scene point appears in a camera at ``other``, minus the pixel's position.
        Computed on every ``step``-th pixel and interpolated (it is smooth but at depth edges).
        """
        cam = self.camera
        rel = np.linalg.inv(other) @ pose
        z = depth[::step, ::step]
        z = np.where(np.isfinite(z), z, np.float32(1e3))
        xs = self.xs[::step].astype(np.float32)[None, :]
        ys = self.ys[::step].astype(np.float32)[:, None]
        q = [
            (np.float32(rel[i, 0]) * xs + np.float32(rel[i, 1]) * ys + np.float32(rel[i, 2])) * z
            + np.float32(rel[i, 3])
            for i in range(3)
        ]
        inv_z = np.float32(1) / np.maximum(q[2], np.float32(NEAR))
        fu = np.float32(cam.fx) * (q[0] * inv_z - xs)
        fv = np.float32(cam.fy) * (q[1] * inv_z - ys)
        small = np.stack([fu, fv], axis=-1)
        return cv2.resize(small, (cam.width, cam.height), interpolation=cv2.INTER_LINEAR)

    # ------------------------------------------------------------------ helpers

    def _screen_rects(self, prims: PrimArrays, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel rectangles ``(P, 4)`` x0 y0 x1 y1 (exclusive; ``-1`` rows are culled) and the
        nearest depth ``(P,)`` of each primitive's bounding box (a lower bound of its depth)."""
        cam = self.camera
        world_to_cam = np.linalg.inv(pose)
        corners = prims.corners().astype(np.float64)  # (P, 8, 3)
        pc = corners @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
        # A box crossing the near plane: clip its edges there, so that the rectangle covers
        # only the part in front of the camera (its projection would be unbounded otherwise).
        a, b = pc[:, _EDGES[:, 0]], pc[:, _EDGES[:, 1]]  # (P, 12, 3)
        za, zb = a[..., 2], b[..., 2]
        crossing = (za < NEAR) != (zb < NEAR)
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(crossing, (NEAR - za) / (zb - za), 0.0)
        cut = a + f[..., None] * (b - a)
        pts = np.concatenate([pc, cut], axis=1)  # (P, 20, 3)
        use = np.concatenate([pc[..., 2] >= NEAR, crossing], axis=1)
        z = np.where(use, np.maximum(pts[..., 2], NEAR), 1.0)
        px = np.where(use, cam.fx * pts[..., 0] / z + cam.cx, np.nan)
        py = np.where(use, cam.fy * pts[..., 1] / z + cam.cy, np.nan)
        out = np.full((len(prims), 4), -1, np.int64)
        seen = use.any(axis=1)
        with np.errstate(invalid="ignore"):
            lim = (
                np.stack(
                    [
                        np.nanmin(px[seen], 1),
                        np.nanmin(py[seen], 1),
                        np.nanmax(px[seen], 1),
                        np.nanmax(py[seen], 1),
                    ],
                    1,
                )
                if seen.any()
                else np.zeros((0, 4))
            )
        x0 = np.clip(np.floor(lim[:, 0]) - 1, 0, cam.width).astype(np.int64)
        y0 = np.clip(np.floor(lim[:, 1]) - 1, 0, cam.height).astype(np.int64)
        x1 = np.clip(np.ceil(lim[:, 2]) + 2, 0, cam.width).astype(np.int64)
        y1 = np.clip(np.ceil(lim[:, 3]) + 2, 0, cam.height).astype(np.int64)
        rect = np.stack([x0, y0, x1, y1], axis=1)
        ok = (x1 > x0) & (y1 > y0)
        idx = np.flatnonzero(seen)[ok]
        out[idx] = rect[ok]
        z = pc[..., 2]
        return out, np.maximum(z.min(axis=1), 0.0).astype(np.float32)

    @staticmethod
    def _shade(points, normals, lighting: Lighting) -> np.ndarray:
        px, py, pz = points
        nx, ny, nz = normals
        shade = (
            np.float32(lighting.ambient + 0.5 * lighting.hemi)
            + np.float32(0.5 * lighting.hemi) * nz
        )
        for light in lighting.lights:
            lx, ly, lz = (np.float32(c) for c in light.position)
            vx, vy, vz = lx - px, ly - py, lz - pz
            dist2 = vx * vx + vy * vy + vz * vz
            ndotl = np.maximum(nx * vx + ny * vy + nz * vz, 0)
            atten = np.float32(light.intensity) / (
                np.sqrt(dist2) * (np.float32(1) + dist2 * np.float32(1 / light.falloff**2))
            )
            shade += ndotl * atten
        return shade

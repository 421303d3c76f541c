"""The multi-view geometry filter: ``geometry`` (USS-SLAM §3.5 / DynaSLAM): keypoints of the
``reference_keyframes`` keyframes with the highest overlap are projected into the current frame;
where the parallax angle is below ``max_parallax_deg`` (30°) and the projected depth exceeds the
measured one by more than ``depth_threshold`` (0.4 m), something moved in front of the static scene:
the pixel seeds a dynamic region grown over the depth image, and the keypoints inside it are
dynamic.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import cv2
import numpy as np

from uss_slam.core.ranges import Range

from ..geometry import invert, project, transform
from .base import DynamicFilter, FilterContext, FilterOutput, values_at

if TYPE_CHECKING:
    from ..map.slam_map import KeyFrame


class GeometryFilter(DynamicFilter):
    """DynaSLAM's multi-view check against the highest-overlap keyframes, with region growing."""

    name = "geometry"
    stage = "post"
    motion = True

    def __init__(
        self,
        reference_keyframes: Annotated[int, Range(min=1)] = 5,
        max_parallax_deg: Annotated[float, Range(gt=0, lt=180)] = 30.0,
        depth_threshold: Annotated[float, Range(gt=0)] = 0.4,
        min_keyframe_age: Annotated[int, Range(min=0)] = 5,
        grow_step: Annotated[float, Range(gt=0)] = 0.05,
        grow_band: Annotated[float, Range(min=0)] = 0.6,
        grow_scale: Annotated[int, Range(min=1)] = 4,
        grow_radius: Annotated[float, Range(min=0)] = 32.0,
        min_seeds: Annotated[int, Range(min=1)] = 2,
        edge_window: Annotated[int, Range(min=1)] = 7,
    ) -> None:  # the ranges: the config's schema (slam.filter_params.geometry.*)
        self.reference_keyframes = int(reference_keyframes)
        self.cos_parallax = float(np.cos(np.radians(max_parallax_deg)))
        self.depth_threshold = float(depth_threshold)
        self.min_keyframe_age = int(min_keyframe_age)
        self.grow_step = float(grow_step)
        self.grow_band = float(grow_band)
        self.grow_scale = int(grow_scale)
        self.grow_radius = float(grow_radius)
        self.min_seeds = int(min_seeds)
        self.edge_radius = max(0, int(edge_window) // 2)

    def references(self, ctx: FilterContext) -> list[int]:
        """Ids of the keyframes with the highest overlap (shared map points) with the frame,
        at least ``min_keyframe_age`` frames old (a moving object must have had time to move)."""
        kfs = ctx.map.keyframes
        old = np.array(
            [
                kf.frame_index <= ctx.frame.index - self.min_keyframe_age and not kf.bad
                for kf in kfs
            ],
            bool,
        )
        if not old.any():
            return []
        matched = ctx.matched if ctx.matched is not None else np.zeros(0, np.int64)
        overlap = ctx.map.covisibility(matched[matched >= 0]).astype(np.float64)
        # Ties (and keyframes sharing nothing) go to the nearest camera positions.
        center = ctx.pose_wc[:3, 3]
        near = np.array([np.linalg.norm(kf.center - center) for kf in kfs])
        score = np.where(old, overlap - 1e-3 * near, -np.inf)
        order = np.argsort(-score, kind="stable")
        return [int(i) for i in order[: self.reference_keyframes] if np.isfinite(score[i])]

    def seeds(self, ctx: FilterContext) -> np.ndarray:
        """``(S, 2)`` pixel positions (distorted image) where a static keyframe point is occluded
        by something nearer than expected: the seeds of dynamic regions."""
        pose_cw = invert(ctx.pose_wc)
        center = ctx.pose_wc[:3, 3]
        depth = ctx.frame.depth
        h, w = depth.shape
        camera = ctx.extractor.camera
        out = []
        for kf_id in self.references(ctx):
            kf = ctx.map.keyframes[kf_id]
            use = kf.features.has_depth & ~kf.dynamic
            if not use.any():
                continue
            world = transform(kf.pose_wc, kf.features.points[use])
            cam = transform(pose_cw, world)
            z = cam[:, 2]
            front = z > 0.05
            world, cam, z = world[front], cam[front], z[front]
            a = world - kf.center
            b = world - center
            cos = (a * b).sum(axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
            if camera.has_distortion:
                xy = cv2.projectPoints(
                    cam.reshape(-1, 1, 3),
                    np.zeros(3),
                    np.zeros(3),
                    camera.matrix,
                    np.asarray(camera.distortion),
                )[0].reshape(-1, 2)
            else:
                xy = project(camera.matrix, cam)
            inside = (xy[:, 0] >= 0) & (xy[:, 0] <= w - 1) & (xy[:, 1] >= 0) & (xy[:, 1] <= h - 1)
            xy, z, cos = xy[inside], z[inside], cos[inside]
            measured = values_at(depth, xy)
            seed = (
                (cos > self.cos_parallax) & (measured > 0) & (z - measured > self.depth_threshold)
            )
            seed[seed] = ~self._at_depth_edge(depth, xy[seed])
            seed[seed] = ~self._seen_by(kf, ctx, xy[seed], measured[seed])
            out.append(xy[seed])
        return np.concatenate(out) if out else np.zeros((0, 2))

    def _seen_by(
        self, kf: KeyFrame, ctx: FilterContext, xy: np.ndarray, measured: np.ndarray
    ) -> np.ndarray:
        """``(S,)`` bool: the keyframe saw the surface now measured at ``xy`` at the same place.

        The reverse check: the seed's 3D point (measured depth, current pose) projected into the
        keyframe lands on the keyframe's own depth within ``depth_threshold``. True for a static
        object that now hides what the keyframe saw behind it (the camera moved), false for an
        object that was not there. Keyframes without a stored depth image pass everything.
        """
        if kf.depth is None or len(xy) == 0:
            return np.zeros(len(xy), bool)
        ex = ctx.extractor
        world = transform(ctx.pose_wc, ex.backproject(ex.undistort(xy), measured))
        cam = transform(kf.pose_cw, world)
        uv = project(ex.camera.matrix, cam)
        scale = kf.depth_stride
        h, w = kf.depth.shape
        col = np.rint(uv[:, 0] / scale).astype(np.int64)
        row = np.rint(uv[:, 1] / scale).astype(np.int64)
        inside = (cam[:, 2] > 0.05) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        seen = np.zeros(len(xy), bool)
        # Any sample of the 3x3 neighbourhood will do: the keyframe depth is subsampled, and a
        # thin static object (a desk leg) may fall between samples.
        z = cam[inside, 2]
        hit = np.zeros(int(inside.sum()), bool)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                kf_depth = kf.depth[
                    np.clip(row[inside] + dy, 0, h - 1), np.clip(col[inside] + dx, 0, w - 1)
                ]
                hit |= (kf_depth > 0) & (np.abs(z - kf_depth) <= self.depth_threshold)
        seen[inside] = hit
        return seen

    def _at_depth_edge(self, depth: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """``(S,)`` bool: the depth around ``xy`` jumps by more than ``depth_threshold``.

        A static object's occlusion boundary also hides keyframe points behind it when the camera
        moves (DynaSLAM notes these false positives); a genuinely moving object shows the depth
        difference over its whole surface, not only at its silhouette, so such seeds are skipped.
        """
        r = self.edge_radius
        if r == 0 or len(xy) == 0:
            return np.zeros(len(xy), bool)
        h, w = depth.shape
        col = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
        row = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
        d = np.arange(-r, r + 1)
        rows = np.clip(row[:, None, None] + d[None, :, None], 0, h - 1)
        cols = np.clip(col[:, None, None] + d[None, None, :], 0, w - 1)
        patch = depth[rows, cols].reshape(len(xy), -1)
        valid = patch > 0
        hi = np.where(valid, patch, -np.inf).max(axis=1)
        lo = np.where(valid, patch, np.inf).min(axis=1)
        return (hi - lo) > self.depth_threshold

    def grow(self, depth: np.ndarray, seeds: np.ndarray) -> np.ndarray:
        """``(H, W)`` bool dynamic region grown from ``seeds`` over the depth image.

        DynaSLAM-style region growing on depth, with bounds of this harness: growth runs on a
        ``grow_scale``-times smaller depth image, from pixel to neighbour while the depth changes
        by less than ``grow_step``, stays within ``grow_band`` of the seed's depth and within
        ``grow_radius`` px of some seed (so a person does not leak into the floor or the desk
        they stand at); regions reached by fewer than ``min_seeds`` seeds are dropped as noise.
        (Robust semantic mapping's Algorithm 1 also bounds dynamic pixels by depth and image
        distance to a dynamic point, with σ1 = 0.1 m and σ2 = 5 px and without growth: that is
        step 2 of the ``object`` filter.)
        """
        h, w = depth.shape
        s = self.grow_scale
        small = np.ascontiguousarray(depth[::s, ::s])
        sh, sw = small.shape
        region = np.zeros((sh, sw), np.uint8)  # 0 free, 1 accepted, 2 rejected
        if len(seeds) == 0:
            return np.zeros((h, w), bool)
        # The small image samples every s-th pixel; a seed starts growth only where that sample
        # has the seed's own depth (near a silhouette the cell may sample the other side).
        cells = np.clip(np.floor(seeds / s).astype(np.int64), 0, [sw - 1, sh - 1])
        own = values_at(depth, seeds)
        cells = cells[np.abs(small[cells[:, 1], cells[:, 0]] - own) <= self.grow_step]
        if len(cells) == 0:
            return np.zeros((h, w), bool)
        flat = cells[:, 1] * sw + cells[:, 0]
        seed_count = np.bincount(flat, minlength=sh * sw).reshape(sh, sw)
        reach = max(1, int(round(self.grow_radius / s)))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
        near = cv2.dilate((seed_count > 0).astype(np.uint8), kernel) > 0
        mask = np.zeros((sh + 2, sw + 2), np.uint8)
        flags = 4 | cv2.FLOODFILL_MASK_ONLY | (255 << 8)
        for cx, cy in np.unique(cells, axis=0):
            d0 = small[cy, cx]
            if region[cy, cx] or d0 <= 0:
                continue
            blocked = (small <= 0) | (np.abs(small - d0) > self.grow_band) | (region > 0) | ~near
            mask[1:-1, 1:-1] = blocked
            cv2.floodFill(small, mask, (int(cx), int(cy)), 0, self.grow_step, self.grow_step, flags)
            new = mask[1:-1, 1:-1] == 255
            region[new] = 1 if seed_count[new].sum() >= self.min_seeds else 2
        full = cv2.resize(
            (region == 1).astype(np.uint8), (sw * s, sh * s), interpolation=cv2.INTER_NEAREST
        )
        return full[:h, :w].astype(bool)

    def __call__(self, ctx: FilterContext) -> FilterOutput:
        if ctx.pose_wc is None:
            return FilterOutput(np.zeros(len(ctx.features), bool))
        region = self.grow(ctx.frame.depth, self.seeds(ctx))
        dynamic = values_at(region, ctx.features.xy)
        return FilterOutput(dynamic, region, len(ctx.features))

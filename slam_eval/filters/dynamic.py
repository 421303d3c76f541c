"""Dynamic-keypoint filters: semantic mask, ego-motion-compensated optical flow, multi-view
geometry, and the object rule. Configurable, composable (run in the listed order), each timed by
the pipeline.

Every filter returns a :class:`FilterOutput`: which keypoints it judges dynamic, optionally the
dynamic pixel region (kept out of the semantic map), and how many keypoints it could judge.
Filters of stage ``"pre"`` run before tracking (they need no pose); ``"post"`` filters run once
the frame's pose is known, and the pose is then re-refined without what they flagged.

- ``semantic`` (USS-SLAM §3.4): keypoints inside the mask of the dynamic classes, dilated by
  ``dilation`` px (a real segmenter's masks are not pixel-exact at object borders).
- ``flow`` (PSPNet-SLAM §III.C, robust semantic mapping §3.1): the camera motion between the
  previous and the current frame is estimated by PnP-RANSAC on keypoints tracked by Lucas–Kanade;
  the previous frame *warped by that motion* would show a static point exactly where the motion
  predicts it, so the flow between the warped previous frame and the current one at a keypoint
  is ``|LK position − motion-predicted position|``; above ``threshold`` (7 px) it is dynamic.
- ``geometry`` (USS-SLAM §3.5 / DynaSLAM): keypoints of the ``reference_keyframes`` keyframes with
  the highest overlap are projected into the current frame; where the parallax angle is below
  ``max_parallax_deg`` (30°) and the projected depth exceeds the measured one by more than
  ``depth_threshold`` (0.4 m), something moved in front of the static scene: the pixel seeds a
  dynamic region grown over the depth image, and the keypoints inside it are dynamic.
- ``object`` (robust semantic mapping §3.3, Algorithm 1, its values Num = 20, σ1 = 0.1 m,
  σ2 = 5 px): step 1, a segmented object (connected component of one class) holding more than
  ``min_points`` keypoints flagged by the motion filters listed before it (``flow``,
  ``geometry``) is dynamic as a whole; step 2, around each of the other flagged keypoints, the
  pixels closer than ``pixel_radius`` in the image and ``depth_radius`` in depth are dynamic too.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import UssSlamError

from ..frontend.orb import Features, OrbExtractor
from ..geometry import from_rvec, invert, project, transform
from ..segmenters.base import class_ids
from ..sequence import Frame

if TYPE_CHECKING:
    from ..mapping.slam_map import KeyFrame
    from ..tracking.tracker import Tracker


@dataclass
class FilterContext:
    """What a filter may look at for the current frame.

    ``labels`` (H, W) uint8 class ids or None; ``pose_wc`` (4, 4) the current pose estimate
    (post-pose filters only); ``matched`` (N,) map point per keypoint (-1 none; post only);
    ``flags`` keypoint flags of the filters that ran before, by name; ``motion_flags`` the union
    of the flags of motion filters (flow, geometry) so far.
    """

    frame: Frame
    features: Features
    labels: np.ndarray | None
    extractor: OrbExtractor
    tracker: Tracker
    previous: Frame | None = None
    pose_wc: np.ndarray | None = None
    matched: np.ndarray | None = None
    flags: dict[str, np.ndarray] = field(default_factory=dict)
    motion_flags: np.ndarray | None = None


@dataclass
class FilterOutput:
    """``dynamic`` (N,) bool; ``region`` (H, W) bool dynamic pixels or None; ``checked`` how many
    keypoints the filter could judge (e.g. the flow filter needs depth and a previous frame)."""

    dynamic: np.ndarray
    region: np.ndarray | None = None
    checked: int = 0


class DynamicFilter(ABC):
    """Base of the filters. ``stage`` says whether it needs the current pose."""

    name: str = "filter"
    stage: Literal["pre", "post"] = "pre"
    needs_labels: bool = False
    motion: bool = False
    """Its flags come from observed motion (the object rule counts them)."""

    @abstractmethod
    def __call__(self, ctx: FilterContext) -> FilterOutput: ...


def _at(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Values of a (H, W) image at float pixel positions ``xy`` (nearest pixel, clamped)."""
    h, w = image.shape[:2]
    col = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
    return image[row, col]


class SemanticFilter(DynamicFilter):
    """Drop keypoints inside the dilated mask of the dynamic classes."""

    name = "semantic"
    stage = "pre"
    needs_labels = True

    def __init__(self, dynamic_classes: Sequence[str] = ("person",), dilation: int = 5) -> None:
        if dilation < 0:
            raise UssSlamError(f"filter semantic: dilation must be >= 0 px, got {dilation}")
        self.ids = class_ids(list(dynamic_classes))
        self.dilation = int(dilation)
        self._lut = np.zeros(256, np.uint8)
        self._lut[self.ids] = 1
        size = 2 * self.dilation + 1
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))

    def mask(self, labels: np.ndarray) -> np.ndarray:
        """``(H, W)`` uint8 1 where a dynamic class is (after dilation)."""
        mask = cv2.LUT(labels, self._lut)
        if self.dilation:
            mask = cv2.dilate(mask, self._kernel)
        return mask

    def __call__(self, ctx: FilterContext) -> FilterOutput:
        if ctx.labels is None:
            raise UssSlamError(
                "filter semantic needs a segmenter (segmenter=labels or an ONNX model)"
            )
        mask = self.mask(ctx.labels)
        dynamic = _at(mask, ctx.features.xy) > 0
        return FilterOutput(dynamic, mask.astype(bool), len(ctx.features))


class FlowFilter(DynamicFilter):
    """Optical flow against the ego-motion-warped previous frame; dynamic if above ``threshold``."""

    name = "flow"
    stage = "pre"
    motion = True

    def __init__(
        self,
        threshold: float = 7.0,
        window: int = 21,
        levels: int = 3,
        ransac_threshold: float = 2.0,
        min_points: int = 12,
    ) -> None:
        if threshold <= 0 or window < 3 or levels < 0:
            raise UssSlamError("filter flow: need threshold > 0, window >= 3 and levels >= 0")
        self.threshold = float(threshold)
        self.window = (int(window), int(window))
        self.levels = int(levels)
        self.ransac_threshold = float(ransac_threshold)
        self.min_points = int(min_points)

    def __call__(self, ctx: FilterContext) -> FilterOutput:
        f = ctx.features
        dynamic = np.zeros(len(f), bool)
        if ctx.previous is None:
            return FilterOutput(dynamic)
        usable = np.flatnonzero(f.has_depth)
        if len(usable) < self.min_points:
            return FilterOutput(dynamic)
        # Track current keypoints back into the previous frame.
        pts = f.xy[usable].reshape(-1, 1, 2).astype(np.float32)
        prev, status, _ = cv2.calcOpticalFlowPyrLK(
            ctx.frame.gray, ctx.previous.gray, pts, None, winSize=self.window, maxLevel=self.levels
        )
        ok = status.reshape(-1).astype(bool)
        usable, prev = usable[ok], prev.reshape(-1, 2)[ok]
        if len(usable) < self.min_points:
            return FilterOutput(dynamic)
        prev_uv = ctx.extractor.undistort(prev)
        k = ctx.extractor.camera.matrix
        found, rvec, tvec, inliers = cv2.solvePnPRansac(
            f.points[usable].reshape(-1, 1, 3),
            prev_uv.reshape(-1, 1, 2),
            k,
            None,
            iterationsCount=100,
            reprojectionError=self.ransac_threshold,
            confidence=0.999,
            flags=cv2.SOLVEPNP_AP3P,
        )
        if not found or inliers is None or len(inliers) < self.min_points:
            return FilterOutput(dynamic)
        inl = inliers.reshape(-1)
        rvec, tvec = cv2.solvePnPRefineLM(
            f.points[usable[inl]].reshape(-1, 1, 3),
            prev_uv[inl].reshape(-1, 1, 2),
            k,
            None,
            rvec,
            tvec,
        )
        predicted = project(k, transform(from_rvec(rvec, tvec), f.points[usable]))
        flow = np.linalg.norm(prev_uv - predicted, axis=1)
        dynamic[usable] = flow > self.threshold
        return FilterOutput(dynamic, None, len(usable))


class GeometryFilter(DynamicFilter):
    """DynaSLAM's multi-view check against the highest-overlap keyframes, with region growing."""

    name = "geometry"
    stage = "post"
    motion = True

    def __init__(
        self,
        reference_keyframes: int = 5,
        max_parallax_deg: float = 30.0,
        depth_threshold: float = 0.4,
        min_keyframe_age: int = 5,
        grow_step: float = 0.05,
        grow_band: float = 0.6,
        grow_scale: int = 4,
        grow_radius: float = 32.0,
        min_seeds: int = 2,
        edge_window: int = 7,
    ) -> None:
        if reference_keyframes < 1 or depth_threshold <= 0 or not 0 < max_parallax_deg < 180:
            raise UssSlamError(
                "filter geometry: need reference_keyframes >= 1, depth_threshold > 0 and "
                "0 < max_parallax_deg < 180"
            )
        if grow_scale < 1 or min_seeds < 1:
            raise UssSlamError("filter geometry: need grow_scale >= 1 and min_seeds >= 1")
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
        tracker = ctx.tracker
        kfs = tracker.map.keyframes
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
        overlap = tracker.map.covisibility(matched[matched >= 0]).astype(np.float64)
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
            kf = ctx.tracker.map.keyframes[kf_id]
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
            measured = _at(depth, xy)
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
        own = _at(depth, seeds)
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
        dynamic = _at(region, ctx.features.xy)
        return FilterOutput(dynamic, region, len(ctx.features))


class ObjectFilter(DynamicFilter):
    """Robust semantic mapping's Algorithm 1 on the keypoints the motion filters flagged.

    Step 1: a segmented object with more than ``min_points`` (Num) flagged keypoints is dynamic.
    Step 2: for every other flagged keypoint ``p`` with depth, the pixels ``P`` with
    ``|D(P) - z_p| < depth_radius`` (σ1, metres) and ``|P - p| < pixel_radius`` (σ2, px) are
    dynamic (pixels without depth are not); ``pixel_radius = 0`` skips step 2. Keypoints on the
    dynamic pixels are dynamic; the pixels are the filter's region (kept out of the semantic map).
    """

    name = "object"
    stage = "post"
    needs_labels = True

    def __init__(
        self,
        min_points: int = 20,
        classes: Sequence[str] | None = None,
        depth_radius: float = 0.1,
        pixel_radius: float = 5.0,
    ) -> None:
        if min_points < 1:
            raise UssSlamError(f"filter object: min_points must be >= 1, got {min_points}")
        if not (depth_radius > 0 and pixel_radius >= 0):
            raise UssSlamError(
                "filter object: need depth_radius > 0 m and pixel_radius >= 0 px, got "
                f"{depth_radius} and {pixel_radius}"
            )
        self.min_points = int(min_points)
        names = [c for c in CLASS_NAMES if c != "background"] if classes is None else classes
        self.ids = class_ids(list(names))
        self.depth_radius = float(depth_radius)
        self.pixel_radius = float(pixel_radius)
        r = max(0, math.ceil(self.pixel_radius) - 1)
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        disc = dx**2 + dy**2 < self.pixel_radius**2
        self._offsets = np.column_stack([dx[disc], dy[disc]])
        """``(K, 2)`` integer pixel offsets closer than ``pixel_radius``."""

    def near(self, depth: np.ndarray, xy: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Step 2: ``(H, W)`` bool pixels closer than ``pixel_radius`` to some keypoint ``xy``
        (S, 2) and within ``depth_radius`` of its depth ``z`` (S,) metres."""
        h, w = depth.shape
        out = np.zeros((h, w), bool)
        if len(xy) == 0 or len(self._offsets) == 0:
            return out
        centre = np.rint(xy).astype(np.int64)
        px = centre[:, None, 0] + self._offsets[None, :, 0]
        py = centre[:, None, 1] + self._offsets[None, :, 1]
        # Offsets are around the rounded pixel; the distance test is to the exact position.
        close = (px - xy[:, None, 0]) ** 2 + (py - xy[:, None, 1]) ** 2 < self.pixel_radius**2
        inside = close & (px >= 0) & (px < w) & (py >= 0) & (py < h)
        px, py = px[inside], py[inside]
        zp = np.broadcast_to(z[:, None], inside.shape)[inside]
        d = depth[py, px]
        hit = (d > 0) & (np.abs(d - zp) < self.depth_radius)
        out[py[hit], px[hit]] = True
        return out

    def objects(self, labels: np.ndarray) -> np.ndarray:
        """``(H, W)`` int32 object id per pixel (0 = no object): connected components per class."""
        out = np.zeros(labels.shape, np.int32)
        next_id = 1
        for c in self.ids:
            if c == IGNORE_INDEX:
                continue
            mask = (labels == c).astype(np.uint8)
            if not mask.any():
                continue
            n, comp = cv2.connectedComponents(mask, connectivity=8)
            out[comp > 0] = comp[comp > 0] + next_id - 1
            next_id += n - 1
        return out

    def __call__(self, ctx: FilterContext) -> FilterOutput:
        if ctx.labels is None:
            raise UssSlamError(
                "filter object needs a segmenter (segmenter=labels or an ONNX model)"
            )
        f = ctx.features
        n = len(f)
        if ctx.motion_flags is None or not ctx.motion_flags.any():
            return FilterOutput(np.zeros(n, bool), None, n)
        objects = self.objects(ctx.labels)
        at = _at(objects, f.xy)
        counts = np.bincount(at[ctx.motion_flags], minlength=int(objects.max()) + 1)
        counts[0] = 0
        moving = np.flatnonzero(counts > self.min_points)
        on_moving = np.isin(at, moving)
        region = np.isin(objects, moving)
        rest = ctx.motion_flags & ~on_moving & f.has_depth
        if self.pixel_radius > 0 and rest.any():
            region |= self.near(ctx.frame.depth, f.xy[rest].astype(np.float64), f.depth[rest])
        if not region.any():
            return FilterOutput(np.zeros(n, bool), None, n)
        return FilterOutput(on_moving | _at(region, f.xy), region, n)


FILTERS: dict[str, type[DynamicFilter]] = {
    "semantic": SemanticFilter,
    "flow": FlowFilter,
    "geometry": GeometryFilter,
    "object": ObjectFilter,
}
"""Filter name (as in ``filters=[...]``) -> class; keyword arguments come from the config."""


def build_filters(
    names: Sequence[str], params: dict[str, dict] | None = None
) -> list[DynamicFilter]:
    """Instantiate filters by name with their parameters (unknown names list the known ones)."""
    params = params or {}
    out: list[DynamicFilter] = []
    for name in names:
        if name not in FILTERS:
            raise UssSlamError(
                f"unknown filter {name!r}; choose from {', '.join(FILTERS)} (filters=[...])"
            )
        if name in {f.name for f in out}:
            raise UssSlamError(f"filter {name!r} is listed twice")
        try:
            out.append(FILTERS[name](**dict(params.get(name, {}) or {})))
        except TypeError as err:
            raise UssSlamError(f"filter {name!r}: bad parameters ({err})") from None
    return out

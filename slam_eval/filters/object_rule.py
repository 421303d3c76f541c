"""The object rule: ``object`` (robust semantic mapping §3.3, Algorithm 1, its values Num = 20, σ1 =
0.1 m, σ2 = 5 px): step 1, a segmented object (connected component of one class) holding more than
``min_points`` keypoints flagged by the motion filters listed before it (``flow``, ``geometry``) is
dynamic as a whole; step 2, around each of the other flagged keypoints, the pixels closer than
``pixel_radius`` in the image and ``depth_radius`` in depth are dynamic too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Annotated

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import UssSlamError
from uss_slam.core.ranges import Range

from ..segmenters.base import class_ids
from .base import DynamicFilter, FilterContext, FilterOutput, values_at


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
        min_points: Annotated[int, Range(min=1)] = 20,
        classes: Sequence[str] | None = None,
        depth_radius: Annotated[float, Range(gt=0)] = 0.1,
        pixel_radius: Annotated[float, Range(min=0)] = 5.0,
    ) -> None:  # the ranges: the config's schema (slam.filter_params.object.*)
        self.min_points = int(min_points)
        names = [c for c in CLASS_NAMES if c != "background"] if classes is None else classes
        self.ids = class_ids(list(names), f"slam.filter_params.{self.name}.classes")
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
        at = values_at(objects, f.xy)
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
        return FilterOutput(on_moving | values_at(region, f.xy), region, n)

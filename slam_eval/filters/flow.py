"""The optical-flow filter: ``flow`` (PSPNet-SLAM §III.C, robust semantic mapping §3.1): the camera
motion between the previous and the current frame is estimated by PnP-RANSAC on keypoints tracked by
Lucas–Kanade; the previous frame *warped by that motion* would show a static point exactly where the
motion predicts it, so the flow between the warped previous frame and the current one at a keypoint
is ``|LK position − motion-predicted position|``; above ``threshold`` (7 px) it is dynamic.
"""

from __future__ import annotations

from typing import Annotated

import cv2
import numpy as np

from uss_slam.core.ranges import Range

from ..geometry import from_rvec, project, transform
from .base import DynamicFilter, FilterContext, FilterOutput


class FlowFilter(DynamicFilter):
    """Optical flow against the ego-motion-warped previous frame; dynamic if above ``threshold``."""

    name = "flow"
    stage = "pre"
    motion = True

    def __init__(
        self,
        threshold: Annotated[float, Range(gt=0)] = 7.0,
        window: Annotated[int, Range(min=3, max=255)] = 21,  # px: past a frame's side
        levels: Annotated[int, Range(min=0, max=16)] = 3,
        ransac_threshold: Annotated[float, Range(gt=0)] = 2.0,
        min_points: Annotated[int, Range(min=4)] = 12,
    ) -> None:  # the ranges: the config's schema (slam.filter_params.flow.*)
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

"""Helpers of the filter tests: the camera of their 320 x 240 frames and ORB features placed at
given points, without the detector."""

from __future__ import annotations

import numpy as np

from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.filters.base import DynamicFilter, FilterContext, FilterOutput
from uss_slam.slam_eval.frontend.orb import Features, OrbExtractor

CAM = TUM_CAMERAS["fr3"].scaled(320, 240)


def features_at(ex: OrbExtractor, xy: np.ndarray, depth: np.ndarray) -> Features:
    """``ex``'s features of keypoints at ``xy`` (level 0, angle 0, response 1, all-zero
    descriptors), their depth sampled from the ``depth`` image."""
    n = len(xy)
    return ex.describe(
        xy.astype(np.float32),
        np.zeros(n, np.int32),
        np.zeros(n, np.float32),
        np.ones(n, np.float32),
        np.zeros((n, 32), np.uint8),
        depth,
    )


class NoStage(DynamicFilter):
    """A filter that declares no stage (refused when it is built)."""

    name = "nostage"

    def __call__(self, ctx: FilterContext) -> FilterOutput:
        return FilterOutput(np.zeros(len(ctx.features), bool))

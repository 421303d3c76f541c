"""The semantic filter: ``semantic`` (USS-SLAM §3.4): keypoints inside the mask of the dynamic
classes, dilated by ``dilation`` px (a real segmenter's masks are not pixel-exact at object
borders).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.ranges import Range

from ..segmenters.base import class_ids
from ..sequence import Frame
from .base import DynamicFilter, FilterContext, FilterOutput, values_at


class SemanticFilter(DynamicFilter):
    """Drop keypoints inside the dilated mask of the dynamic classes."""

    name = "semantic"
    stage = "pre"
    needs_labels = True
    masks_input = True

    def __init__(
        self,
        dynamic_classes: Sequence[str] = ("person",),
        dilation: Annotated[int, Range(min=0)] = 5,
    ) -> None:  # the ranges: the config's schema (slam.filter_params.semantic.*)
        key = f"slam.filter_params.{self.name}.dynamic_classes"
        self.ids = class_ids(list(dynamic_classes), key)
        self.dilation = int(dilation)
        self._lut = np.zeros(256, np.uint8)
        self._lut[self.ids] = 1
        size = 2 * self.dilation + 1
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))

    def idle_reason(self) -> str | None:
        if len(self.ids):
            return None
        return "dynamic_classes is empty: the semantic filter drops no keypoint"

    def mask(self, labels: np.ndarray) -> np.ndarray:
        """``(H, W)`` uint8 1 where a dynamic class is (after dilation)."""
        mask = cv2.LUT(labels, self._lut)
        if self.dilation:
            mask = cv2.dilate(mask, self._kernel)
        return mask

    def input_region(self, frame: Frame, labels: np.ndarray | None) -> np.ndarray | None:
        """``(H, W)`` bool: the dilated mask of the dynamic classes (:meth:`mask`); None
        without labels."""
        return None if labels is None else self.mask(labels) > 0

    def input_settings(self) -> dict[str, Any]:
        """``dynamic_classes`` (names) and ``dilation`` (px)."""
        return {
            "dynamic_classes": [CLASS_NAMES[int(i)] for i in self.ids],
            "dilation": self.dilation,
        }

    def __call__(self, ctx: FilterContext) -> FilterOutput:
        if ctx.labels is None:
            raise UssSlamError(
                "filter semantic needs a segmenter (segmenter=labels or an ONNX model)"
            )
        mask = self.mask(ctx.labels)
        dynamic = values_at(mask, ctx.features.xy) > 0
        return FilterOutput(dynamic, mask.astype(bool), len(ctx.features))

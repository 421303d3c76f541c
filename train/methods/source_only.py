"""Source-only training: the segmentation loss on labelled source images, nothing on the
target (the paper's "without ATL" baseline)."""

from __future__ import annotations

from typing import ClassVar

from uss_slam.train.methods.base import (
    Method,
    StepValues,
    TrainBatch,
    TrainingModule,
    segmenter_step,
)


class SourceOnly(Method):
    """``model/method=source_only``: one SGD step of the segmenter on ``L_seg`` per iteration."""

    name: ClassVar[str] = "source_only"
    adapts: ClassVar[bool] = False

    def training_step(self, module: TrainingModule, batch: TrainBatch) -> StepValues:
        return segmenter_step(module, batch["source"]).values

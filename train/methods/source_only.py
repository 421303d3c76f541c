"""Source-only training: the segmentation loss on labelled source images, nothing on the
target (the paper's "without ATL" baseline). The discriminators are never used."""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

from uss_slam.train.methods.base import Method, StepValues, TrainBatch, segmenter_step

if TYPE_CHECKING:
    from uss_slam.train.module import AdversarialSegmentation


class SourceOnly(Method):
    """``model/method=source_only``: one SGD step of the segmenter on ``L_seg`` per iteration."""

    name: ClassVar[str] = "source_only"
    adapts: ClassVar[bool] = False
    trains_discriminators: ClassVar[bool] = False

    def training_step(self, module: AdversarialSegmentation, batch: TrainBatch) -> StepValues:
        return segmenter_step(module, batch["source"]).values

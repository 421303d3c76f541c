"""MinEnt: direct entropy minimisation on the target (Vu et al., ADVENT, CVPR 2019; its code's
``train_minent``).

One iteration: source forward with ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)``, target
forward with ``L_ent = λ_ent_aux·E(aux) + λ_ent_main·E(main)``, one SGD step of the segmenter on
the sum. ``E`` is the mean over pixels of the entropy normalised by ``log C`` (ADVENT's
``entropy_loss``) of the softmax of the head's logits upsampled to image size. No discriminators
are built.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import torch.nn.functional as F
from torch import Tensor

from uss_slam.core.errors import UssSlamError
from uss_slam.models.deeplab import SegmenterOutput
from uss_slam.train.losses import upsample
from uss_slam.train.methods.advent import self_information
from uss_slam.train.methods.base import (
    Method,
    StepValues,
    TargetLoss,
    TrainBatch,
    segmenter_step,
)

if TYPE_CHECKING:
    from uss_slam.train.module import AdversarialSegmentation


def entropy_loss(logits: Tensor, size: tuple[int, int]) -> Tensor:
    """Mean normalised entropy (0..1) of the softmax of ``(N, C, h, w)`` logits upsampled to
    ``size = (H, W)``: ``mean_{n,h,w} sum_c -P log P / log C``."""
    info = self_information(F.log_softmax(upsample(logits, size), dim=1))
    return info.sum(dim=1).mean()


class MinEnt(Method):
    """``model/method=minent``: source segmentation + weighted target entropy.

    Args:
        lambda_ent_aux: weight of the aux head's target entropy (ADVENT: ``LAMBDA_ENT_AUX``
            0.0002).
        lambda_ent_main: weight of the main head's target entropy (ADVENT: ``LAMBDA_ENT_MAIN``
            0.001).
    """

    name: ClassVar[str] = "minent"
    adapts: ClassVar[bool] = True
    trains_discriminators: ClassVar[bool] = False

    def __init__(self, lambda_ent_aux: float = 0.0002, lambda_ent_main: float = 0.001) -> None:
        super().__init__()
        for key, value in (
            ("lambda_ent_aux", lambda_ent_aux),
            ("lambda_ent_main", lambda_ent_main),
        ):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
                raise UssSlamError(f"model.method.{key} must be a number >= 0, got {value!r}")
        self.lambda_ent_aux = float(lambda_ent_aux)
        self.lambda_ent_main = float(lambda_ent_main)

    def training_step(self, module: AdversarialSegmentation, batch: TrainBatch) -> StepValues:
        images_trg = batch["target"]["image"]
        size = images_trg.shape[-2:]

        def entropy(pred: SegmenterOutput) -> TargetLoss:
            return TargetLoss(
                "loss_ent_trg",
                "loss_ent",
                entropy_loss(pred.aux, size),
                entropy_loss(pred.main, size),
                (self.lambda_ent_aux, self.lambda_ent_main),
            )

        return segmenter_step(module, batch["source"], images_trg, entropy).values

    def extra_repr(self) -> str:
        return (
            f"name={self.name!r}, lambda_ent_aux={self.lambda_ent_aux}, "
            f"lambda_ent_main={self.lambda_ent_main}"
        )

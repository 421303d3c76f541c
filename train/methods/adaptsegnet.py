"""AdaptSegNet: adversarial output-space adaptation with two discriminators (the paper's
Algorithm 1; Tsai et al. 2018, multi-level).

One iteration:

1. source forward, ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)`` (logits upsampled to the
   label size);
2. target forward, ``L_adv = λ_adv_aux·BCE(D_aux(P_aux), 0) + λ_adv_main·BCE(D_main(P_main), 0)``
   with the discriminators frozen (``P`` = softmax of the logits upsampled to image size; 0 =
   "source"); one SGD step of the segmenter on ``L_seg + L_adv``;
3. + 4. discriminators on the detached source (label 0) and target (label 1) softmax maps;
   one Adam step of both discriminators.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar, cast

import torch.nn.functional as F
from torch import Tensor

from uss_slam.models.deeplab import SegmenterOutput
from uss_slam.train.losses import SOURCE_LABEL, domain_loss, upsample
from uss_slam.train.methods.base import (
    Method,
    StepValues,
    TargetLoss,
    TrainBatch,
    discriminator_scalars,
    discriminator_step,
    segmenter_step,
)

if TYPE_CHECKING:
    from uss_slam.train.module import AdversarialSegmentation


class AdaptSegNet(Method):
    """The paper's method (``model/method=adaptsegnet``, the default); loss weights are
    ``model.loss``."""

    name: ClassVar[str] = "adaptsegnet"
    adapts: ClassVar[bool] = True
    trains_discriminators: ClassVar[bool] = True

    def target_map(self, logits: Tensor) -> Tensor:
        """What a discriminator sees of target ``(N, C, H, W)`` logits (upsampled to image
        size): their softmax ``P``. Subclasses (ADVENT) change only this and :meth:`source_map`."""
        return F.softmax(logits, dim=1)

    def source_map(self, log_probs: Tensor) -> Tensor:
        """The same map of the detached source log-probabilities the source loss computed."""
        return log_probs.exp()

    def training_step(self, module: AdversarialSegmentation, batch: TrainBatch) -> StepValues:
        w = module.loss_weights
        images_trg = batch["target"]["image"]
        size = images_trg.shape[-2:]

        def adversarial(pred_trg: SegmenterOutput) -> TargetLoss:
            # (2) the target maps through the frozen discriminators, labelled "source".
            maps = (
                self.target_map(upsample(pred_trg.aux, size)),
                self.target_map(upsample(pred_trg.main, size)),
            )
            return TargetLoss(
                "loss_adv_trg",
                "loss_adv",
                domain_loss(module.d_aux(maps[0]), SOURCE_LABEL),
                domain_loss(module.d_main(maps[1]), SOURCE_LABEL),
                (w.lambda_adv_aux, w.lambda_adv_main),
                keep=maps,
            )

        # (1) + (2): one segmenter step on the source loss and the adversarial loss.
        with module.discriminators_frozen():
            seg = segmenter_step(module, batch["source"], images_trg, adversarial)
        # (3) + (4): the source maps come from the log-softmax the loss already computed.
        term = cast(TargetLoss, seg.target)
        source_maps = (
            self.source_map(seg.source.log_probs[0].detach()),
            self.source_map(seg.source.log_probs[1].detach()),
        )
        step = seg.values
        step.update(discriminator_step(module, source_maps, term.keep, seg.batched))
        return step

    def train_scalars(self, step: StepValues) -> dict[str, Tensor]:
        scalars = {
            f"train/{name}": step[name]
            for name in (
                "loss_seg_src_aux",
                "loss_seg_src_main",
                "loss_adv_trg_aux",
                "loss_adv_trg_main",
            )
        }
        scalars.update(discriminator_scalars(step))
        return scalars

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

from typing import TYPE_CHECKING, ClassVar

import torch.nn.functional as F
from torch import Tensor

from uss_slam.train.losses import SOURCE_LABEL, domain_loss, upsample
from uss_slam.train.methods.base import (
    DomainPass,
    Method,
    SourceSegmentation,
    StepValues,
    TrainBatch,
    can_batch_domains,
    check_finite,
    discriminator_scalars,
    discriminator_step,
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
        opt_seg, _ = module.optimizers()
        images_src, images_trg = batch["source"]["image"], batch["target"]["image"]
        batched = can_batch_domains(module, images_src, images_trg)

        with module.discriminators_frozen():
            opt_seg.zero_grad()
            with DomainPass(
                module.segmenter, images_src, images_trg, module.manual_backward, batched
            ) as seg:
                # (1) segmentation loss on the source images, both heads.
                src = SourceSegmentation(
                    seg.source(), batch["source"]["label"], w, module.iteration
                )
                seg.backward(src.loss)
                # (2) adversarial loss on the target images through the frozen discriminators.
                pred_trg = seg.target()
                size = images_trg.shape[-2:]
                prob_trg = (
                    self.target_map(upsample(pred_trg.aux, size)),
                    self.target_map(upsample(pred_trg.main, size)),
                )
                adv_aux = domain_loss(module.d_aux(prob_trg[0]), SOURCE_LABEL)
                adv_main = domain_loss(module.d_main(prob_trg[1]), SOURCE_LABEL)
                loss_adv = w.lambda_adv_aux * adv_aux + w.lambda_adv_main * adv_main
                check_finite(
                    module.iteration,
                    loss_adv_trg_aux=adv_aux,
                    loss_adv_trg_main=adv_main,
                    loss_adv=loss_adv,
                )
                seg.backward(loss_adv)
            opt_seg.step()

        # (3) + (4): the source maps come from the log-softmax the loss already computed.
        step = dict(src.values)
        step["loss_adv_trg_aux"] = adv_aux.detach()
        step["loss_adv_trg_main"] = adv_main.detach()
        source_maps = (
            self.source_map(src.log_probs[0].detach()),
            self.source_map(src.log_probs[1].detach()),
        )
        step.update(discriminator_step(module, source_maps, prob_trg, batched))
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

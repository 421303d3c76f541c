"""ADVENT (AdvEnt): adversarial training on weighted self-information maps (Vu et al., CVPR 2019,
multi-level as in its code, valeoai/ADVENT).

The same iteration as AdaptSegNet (:mod:`.adaptsegnet`) with one change: the discriminators see
the *weighted self-information map* ``I = -P·log P / log C`` of each head (per class, ``P`` the
softmax of the logits upsampled to image size, ``C`` classes; ADVENT's ``prob_2_entropy``) instead
of ``P``. Summed over classes ``I`` is the normalised entropy (0..1): the target is pushed
towards the low-entropy, confident predictions of the source.

One iteration:

1. source forward, ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)``;
2. target forward, ``L_adv = λ_adv_aux·BCE(D_aux(I_aux), 0) + λ_adv_main·BCE(D_main(I_main), 0)``
   with the discriminators frozen; one SGD step of the segmenter;
3. + 4. discriminators on the detached source (label 0) and target (label 1) maps ``I``.

ADVENT's weights (``configs/model/method/advent.yaml`` sets them as ``model.loss``):
``λ_adv_main 0.001, λ_adv_aux 0.0002`` (its ``LAMBDA_ADV_MAIN`` / ``LAMBDA_ADV_AUX``), ten times
below AdaptSegNet's. Unlike ADVENT's code the discriminator losses are not halved (Adam is
invariant to that scale) and the optimisers are the project's (ADVENT: SGD without Nesterov,
weight decay 5e-4).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar

import torch.nn.functional as F
from torch import Tensor

from uss_slam.train.losses import SOURCE_LABEL, domain_loss, upsample
from uss_slam.train.methods.adaptsegnet import AdaptSegNet
from uss_slam.train.methods.base import (
    DomainPass,
    Method,
    SourceSegmentation,
    StepValues,
    TrainBatch,
    can_batch_domains,
    check_finite,
    discriminator_step,
)

if TYPE_CHECKING:
    from uss_slam.train.module import AdversarialSegmentation


def self_information(log_probs: Tensor) -> Tensor:
    """ADVENT's weighted self-information map ``-P·log P / log C`` of ``(N, C, H, W)``
    log-probabilities, same shape, values in ``[0, 1/(e·ln C)]``; its sum over classes is the
    entropy normalised to ``[0, 1]``. From log-probabilities (not ``P + ε``): exact where
    ``P`` underflows (``0·log 0 = 0``)."""
    classes = log_probs.shape[1]
    if classes < 2:
        raise ValueError(f"self-information needs at least 2 classes, got {classes}")
    return -(log_probs.exp() * log_probs) / math.log(classes)


class AdvEnt(Method):
    """``model/method=advent``: AdaptSegNet's iteration with the discriminators on the weighted
    self-information maps; loss weights are ``model.loss`` (ADVENT's by default)."""

    name: ClassVar[str] = "advent"
    adapts: ClassVar[bool] = True
    trains_discriminators: ClassVar[bool] = True

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
                # (2) adversarial loss on the target's self-information maps.
                pred_trg = seg.target()
                size = images_trg.shape[-2:]
                info_trg = (
                    self_information(F.log_softmax(upsample(pred_trg.aux, size), dim=1)),
                    self_information(F.log_softmax(upsample(pred_trg.main, size), dim=1)),
                )
                adv_aux = domain_loss(module.d_aux(info_trg[0]), SOURCE_LABEL)
                adv_main = domain_loss(module.d_main(info_trg[1]), SOURCE_LABEL)
                loss_adv = w.lambda_adv_aux * adv_aux + w.lambda_adv_main * adv_main
                check_finite(
                    module.iteration,
                    loss_adv_trg_aux=adv_aux,
                    loss_adv_trg_main=adv_main,
                    loss_adv=loss_adv,
                )
                seg.backward(loss_adv)
            opt_seg.step()

        # (3) + (4) on the maps of the log-softmax the source loss already computed.
        step = dict(src.values)
        step["loss_adv_trg_aux"] = adv_aux.detach()
        step["loss_adv_trg_main"] = adv_main.detach()
        source_maps = (
            self_information(src.log_probs[0].detach()),
            self_information(src.log_probs[1].detach()),
        )
        step.update(discriminator_step(module, source_maps, info_trg, batched))
        return step

    # The same logged keys as AdaptSegNet (train/loss_adv_trg_*, train/loss_d_*, train/d_acc_*).
    train_scalars = AdaptSegNet.train_scalars

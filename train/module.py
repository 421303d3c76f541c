"""``AdversarialSegmentation``: the paper's adaptation method as a LightningModule.

The segmenter (a plain :class:`~uss_slam.models.DeepLabV2`) never sees domains; this module
owns the two discriminators, the losses, the optimisers and one training iteration = Algorithm 1:

1. source forward, ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)`` (logits upsampled to the
   label size), backward;
2. target forward, ``L_adv = λ_adv_aux·BCE(D_aux(P_aux), 0) + λ_adv_main·BCE(D_main(P_main), 0)``
   with the discriminators frozen (``P`` = softmax of the logits upsampled to image size; 0 =
   "source"), backward; one SGD step of the segmenter;
3. + 4. discriminators on the detached source (label 0) and target (label 1) softmax maps;
   one Adam step of both discriminators.

``adaptation=False`` runs step 1 only: the source-only baseline ("without ATL").
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Sequence
from dataclasses import asdict
from typing import Any

import torch
import torch.nn.functional as F
from lightning.pytorch import LightningModule
from torch import Tensor, nn
from torch.nn.modules.batchnorm import _BatchNorm
from torch.optim import Optimizer
from torchmetrics.classification import MulticlassJaccardIndex

from uss_slam.datasets.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.datasets.errors import UssSlamError
from uss_slam.models.deeplab import DeepLabV2, SegmenterOutput
from uss_slam.train.losses import (
    SOURCE_LABEL,
    TARGET_LABEL,
    LossWeights,
    domain_accuracy,
    domain_loss,
    segmentation_loss,
    upsample,
)
from uss_slam.train.schedules import PolyLR

log = logging.getLogger(__name__)

OptimizerFactory = Callable[..., Optimizer]


class NonFiniteLossError(UssSlamError):
    """A loss became NaN or infinite; raised before any optimiser step applies it."""


class AdversarialSegmentation(LightningModule):
    """Adversarial output-space adaptation of a two-head segmenter (manual optimisation).

    Args:
        net: the segmenter; ``net(images)`` returns ``(aux, main)`` logits and
            ``net.param_groups(lr, head_lr_mult)`` its optimiser groups.
        discriminator: factory called twice (``d_aux``, ``d_main``), e.g. a Hydra ``_partial_``
            :class:`~uss_slam.models.PatchDiscriminator` with ``in_channels = num_classes``.
        optimizer: segmenter optimiser factory taking ``params`` (SGD, with ``lr``).
        d_optimizer: discriminator optimiser factory taking ``params`` (Adam).
        loss: the four loss weights.
        max_iters: training iterations (own counter: ``global_step`` counts optimiser steps);
            the poly schedules decay to 0 there and training stops.
        poly_power: exponent of the poly schedules.
        head_lr_mult: learning-rate multiplier of the segmenter heads.
        adaptation: ``False`` = source-only training; the discriminators are never used.
        class_names: names for ``val/IoU/<class>``; their count is the number of classes.
        batch_domains: run source and target through one segmenter forward and one
            discriminator pass per head when no layer uses batch statistics (frozen BN) and the
            crops have one size. Identical losses and gradients; peak activation memory holds
            both domains at once (set ``False`` on a tight GPU).
        channels_last: NHWC memory layout for the networks and inputs (same results).
    """

    def __init__(
        self,
        net: DeepLabV2,
        discriminator: Callable[[], nn.Module],
        optimizer: OptimizerFactory,
        d_optimizer: OptimizerFactory,
        loss: LossWeights | None = None,
        max_iters: int = 250_000,
        poly_power: float = 0.9,
        head_lr_mult: float = 10.0,
        adaptation: bool = True,
        class_names: Sequence[str] = CLASS_NAMES,
        batch_domains: bool = True,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        if max_iters <= 0:
            raise UssSlamError(f"model.max_iters must be positive, got {max_iters}")
        self.automatic_optimization = False
        self.segmenter = net
        self.d_aux = discriminator()
        self.d_main = discriminator()
        self.optimizer_factory = optimizer
        self.d_optimizer_factory = d_optimizer
        self.loss_weights = loss if loss is not None else LossWeights()
        self.max_iters = max_iters
        self.poly_power = poly_power
        self.head_lr_mult = head_lr_mult
        self.adaptation = adaptation
        self.class_names = tuple(class_names)
        self.batch_domains = batch_domains
        self.channels_last = channels_last
        self.iteration = 0
        """Completed training iterations (saved in checkpoints)."""
        self.val_iou = MulticlassJaccardIndex(
            num_classes=len(self.class_names),
            average="none",
            ignore_index=IGNORE_INDEX,
            zero_division=float("nan"),
        )
        # Plain values only, so checkpoints load with torch.load(weights_only=True).
        self.save_hyperparameters(
            {
                "loss": asdict(self.loss_weights),
                "max_iters": max_iters,
                "poly_power": poly_power,
                "head_lr_mult": head_lr_mult,
                "adaptation": adaptation,
                "class_names": list(self.class_names),
                "backbone": getattr(net, "backbone_name", type(net).__name__),
            },
            logger=False,
        )

    # ------------------------------------------------------------------ optimisers

    def configure_optimizers(self) -> tuple[list[Optimizer], list[PolyLR]]:
        lr = getattr(self.optimizer_factory, "keywords", {}).get("lr")
        if lr is None:
            raise UssSlamError("model.optimizer must set lr (the backbone learning rate)")
        opt_seg = self.optimizer_factory(params=self.segmenter.param_groups(lr, self.head_lr_mult))
        opt_d = self.d_optimizer_factory(
            params=itertools.chain(self.d_aux.parameters(), self.d_main.parameters())
        )
        schedules = [PolyLR(opt, self.max_iters, self.poly_power) for opt in (opt_seg, opt_d)]
        return [opt_seg, opt_d], schedules

    # ------------------------------------------------------------------ training

    def _check_finite(self, **losses: Tensor) -> None:
        for name, value in losses.items():
            if not bool(torch.isfinite(value)):
                raise NonFiniteLossError(
                    f"non-finite {name} ({value.item()}) at iteration {self.iteration}: training "
                    "stopped before applying it; the last checkpoint written is the last good state"
                )

    def forward(self, images: Tensor) -> SegmenterOutput:
        return self.segmenter(images)

    def setup(self, stage: str) -> None:
        if self.channels_last:
            for net in (self.segmenter, self.d_aux, self.d_main):
                net.to(memory_format=torch.channels_last)

    def _prepare(self, images: Tensor) -> Tensor:
        return (
            images.contiguous(memory_format=torch.channels_last) if self.channels_last else images
        )

    def _batch_statistics(self) -> bool:
        """True when a segmenter layer normalises with batch statistics (unfrozen BatchNorm in
        train mode): then source and target must not share a forward pass."""
        return any(m.training for m in self.segmenter.modules() if isinstance(m, _BatchNorm))

    def training_step(self, batch: dict[str, dict[str, Any]], batch_idx: int) -> Tensor:
        opt_seg, opt_d = self.optimizers()
        sched_seg, sched_d = self.lr_schedulers()
        w = self.loss_weights
        logged: dict[str, Tensor] = {}
        labels = batch["source"]["label"]
        images_src = self._prepare(batch["source"]["image"])
        images_trg = self._prepare(batch["target"]["image"])
        n_src = images_src.shape[0]
        # Source and target through one forward (and later one discriminator pass per head)
        # when every layer treats samples independently: same numbers, better CPU/GPU use.
        batched = (
            self.adaptation
            and self.batch_domains
            and images_src.shape[1:] == images_trg.shape[1:]
            and not self._batch_statistics()
        )

        # (1) segmentation loss on the source image, both heads.
        self.toggle_optimizer(opt_seg)
        opt_seg.zero_grad()
        if batched:
            both = self.segmenter(torch.cat([images_src, images_trg]))
            pred_src = SegmenterOutput(both.aux[:n_src], both.main[:n_src])
            pred_trg = SegmenterOutput(both.aux[n_src:], both.main[n_src:])
        else:
            pred_src = self.segmenter(images_src)
        logp_src_aux = F.log_softmax(upsample(pred_src.aux, labels.shape[-2:]), dim=1)
        logp_src_main = F.log_softmax(upsample(pred_src.main, labels.shape[-2:]), dim=1)
        loss_seg_aux = segmentation_loss(logp_src_aux, labels)
        loss_seg_main = segmentation_loss(logp_src_main, labels)
        loss_seg = w.lambda_seg_aux * loss_seg_aux + w.lambda_seg_main * loss_seg_main
        self._check_finite(
            loss_seg_src_aux=loss_seg_aux, loss_seg_src_main=loss_seg_main, loss_seg=loss_seg
        )
        if not batched:
            self.manual_backward(loss_seg)  # frees the source graph before the target pass
        logged["train/loss_seg_src_aux"] = loss_seg_aux.detach()
        logged["train/loss_seg_src_main"] = loss_seg_main.detach()

        if self.adaptation:
            # (2) adversarial loss on the target image through the frozen discriminators.
            if not batched:
                pred_trg = self.segmenter(images_trg)
            size = images_trg.shape[-2:]
            prob_trg_aux = F.softmax(upsample(pred_trg.aux, size), dim=1)
            prob_trg_main = F.softmax(upsample(pred_trg.main, size), dim=1)
            loss_adv_aux = domain_loss(self.d_aux(prob_trg_aux), SOURCE_LABEL)
            loss_adv_main = domain_loss(self.d_main(prob_trg_main), SOURCE_LABEL)
            loss_adv = w.lambda_adv_aux * loss_adv_aux + w.lambda_adv_main * loss_adv_main
            self._check_finite(
                loss_adv_trg_aux=loss_adv_aux, loss_adv_trg_main=loss_adv_main, loss_adv=loss_adv
            )
            self.manual_backward(loss_seg + loss_adv if batched else loss_adv)
            logged["train/loss_adv_trg_aux"] = loss_adv_aux.detach()
            logged["train/loss_adv_trg_main"] = loss_adv_main.detach()
        opt_seg.step()
        self.untoggle_optimizer(opt_seg)

        if self.adaptation:
            # (3) + (4) discriminators on detached source (0) and target (1) softmax maps
            # (the source softmax is exp of the log-softmax the loss already computed).
            self.toggle_optimizer(opt_d)
            opt_d.zero_grad()
            src_aux, src_main = logp_src_aux.detach().exp(), logp_src_main.detach().exp()
            trg_aux, trg_main = prob_trg_aux.detach(), prob_trg_main.detach()
            if batched:
                out_aux = self.d_aux(torch.cat([src_aux, trg_aux]))
                out_main = self.d_main(torch.cat([src_main, trg_main]))
                d_src_aux, d_trg_aux = out_aux[:n_src], out_aux[n_src:]
                d_src_main, d_trg_main = out_main[:n_src], out_main[n_src:]
            else:
                d_src_aux, d_src_main = self.d_aux(src_aux), self.d_main(src_main)
            loss_d_src_aux = domain_loss(d_src_aux, SOURCE_LABEL)
            loss_d_src_main = domain_loss(d_src_main, SOURCE_LABEL)
            self._check_finite(loss_d_src_aux=loss_d_src_aux, loss_d_src_main=loss_d_src_main)
            if not batched:
                self.manual_backward(loss_d_src_aux + loss_d_src_main)
                d_trg_aux, d_trg_main = self.d_aux(trg_aux), self.d_main(trg_main)
            loss_d_trg_aux = domain_loss(d_trg_aux, TARGET_LABEL)
            loss_d_trg_main = domain_loss(d_trg_main, TARGET_LABEL)
            self._check_finite(loss_d_trg_aux=loss_d_trg_aux, loss_d_trg_main=loss_d_trg_main)
            loss_d_trg = loss_d_trg_aux + loss_d_trg_main
            self.manual_backward(
                loss_d_trg + loss_d_src_aux + loss_d_src_main if batched else loss_d_trg
            )
            opt_d.step()
            self.untoggle_optimizer(opt_d)
            sched_d.step()
            with torch.no_grad():
                logged["train/loss_d_aux"] = loss_d_src_aux.detach() + loss_d_trg_aux.detach()
                logged["train/loss_d_main"] = loss_d_src_main.detach() + loss_d_trg_main.detach()
                logged["train/d_acc_aux"] = 0.5 * (
                    domain_accuracy(d_src_aux, SOURCE_LABEL)
                    + domain_accuracy(d_trg_aux, TARGET_LABEL)
                )
                logged["train/d_acc_main"] = 0.5 * (
                    domain_accuracy(d_src_main, SOURCE_LABEL)
                    + domain_accuracy(d_trg_main, TARGET_LABEL)
                )
        sched_seg.step()
        self.iteration += 1
        self.log_dict(logged, on_step=True, on_epoch=False, batch_size=n_src)
        self.log("iteration", float(self.iteration), on_step=True, prog_bar=True, logger=False)
        return loss_seg.detach()

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> int | None:
        if self.iteration >= self.max_iters:
            self.trainer.should_stop = True
            return -1  # resumed a finished run: skip the rest of the epoch
        return None

    def on_train_batch_end(self, outputs: Any, batch: Any, batch_idx: int) -> None:
        if self.iteration >= self.max_iters:
            self.trainer.should_stop = True

    # ------------------------------------------------------------------ validation

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        labels = batch["label"]
        logits = upsample(self.segmenter(self._prepare(batch["image"])).main, labels.shape[-2:])
        self.val_iou.update(logits.argmax(dim=1), labels)

    def on_validation_epoch_end(self) -> None:
        iou = self.val_iou.compute()
        self.val_iou.reset()
        self.log_dict({f"val/IoU/{name}": iou[i] for i, name in enumerate(self.class_names)})
        self.log("val/mIoU", torch.nanmean(iou), prog_bar=True)

    # ------------------------------------------------------------------ checkpoints

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["iteration"] = self.iteration

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        if "iteration" not in checkpoint:
            raise UssSlamError("checkpoint has no 'iteration': not written by uss-train")
        self.iteration = int(checkpoint["iteration"])

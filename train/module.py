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

import contextlib
import itertools
import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict
from typing import Any

import torch
import torch.nn.functional as F
from lightning.pytorch import LightningModule
from torch import Tensor, nn
from torch.nn.modules.batchnorm import _BatchNorm
from torch.optim import Optimizer
from torchmetrics.classification import MulticlassConfusionMatrix

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import UssSlamError
from uss_slam.core.seg_metrics import iou_per_class
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
        self._step_values: tuple[dict[str, Tensor], int] | None = None
        # Pixel counts (truth x prediction) summed over the validation set and, under DDP,
        # over the ranks (a torchmetrics state); the IoUs come from uss_slam.core.seg_metrics.
        self.val_confusion = MulticlassConfusionMatrix(
            num_classes=len(self.class_names), ignore_index=IGNORE_INDEX
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
        # One host sync for all the losses of a backward pass; names only on failure.
        if bool(torch.isfinite(torch.stack([v.detach() for v in losses.values()])).all()):
            return
        for name, value in losses.items():
            if not bool(torch.isfinite(value)):
                raise NonFiniteLossError(
                    f"non-finite {name} ({value.item()}) at iteration {self.iteration}: training "
                    "stopped before applying it; the last checkpoint written is the last good state"
                )

    @contextlib.contextmanager
    def _discriminators_frozen(self) -> Iterator[None]:
        """``requires_grad=False`` on the discriminators' parameters while the segmenter trains
        (restored afterwards, also on errors). Lightning's ``toggle_optimizer`` does the same
        over every parameter of every optimiser at each call; the discriminator step needs no
        freezing at all since its inputs are detached."""
        params = [p for d in (self.d_aux, self.d_main) for p in d.parameters() if p.requires_grad]
        for p in params:
            p.requires_grad_(False)
        try:
            yield
        finally:
            for p in params:
                p.requires_grad_(True)

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
        # Detached values for the train/* scalars; turned into the logged numbers only on
        # logging steps (see on_train_batch_end).
        step: dict[str, Tensor] = {}
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

        with self._discriminators_frozen():
            # (1) segmentation loss on the source image, both heads.
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
            step["loss_seg_src_aux"] = loss_seg_aux.detach()
            step["loss_seg_src_main"] = loss_seg_main.detach()

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
                    loss_adv_trg_aux=loss_adv_aux,
                    loss_adv_trg_main=loss_adv_main,
                    loss_adv=loss_adv,
                )
                self.manual_backward(loss_seg + loss_adv if batched else loss_adv)
                step["loss_adv_trg_aux"] = loss_adv_aux.detach()
                step["loss_adv_trg_main"] = loss_adv_main.detach()
            opt_seg.step()

        if self.adaptation:
            # (3) + (4) discriminators on detached source (0) and target (1) softmax maps
            # (the source softmax is exp of the log-softmax the loss already computed). The
            # inputs are detached, so the segmenter needs no freezing here.
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
            sched_d.step()
            for name, value in (
                ("loss_d_src_aux", loss_d_src_aux),
                ("loss_d_trg_aux", loss_d_trg_aux),
                ("loss_d_src_main", loss_d_src_main),
                ("loss_d_trg_main", loss_d_trg_main),
                ("d_src_aux", d_src_aux),
                ("d_trg_aux", d_trg_aux),
                ("d_src_main", d_src_main),
                ("d_trg_main", d_trg_main),
            ):
                step[name] = value.detach()
        sched_seg.step()
        self.iteration += 1
        self._step_values = (step, n_src)
        # Every step: the progress bar and the checkpoint file names read it.
        self.log("iteration", float(self.iteration), on_step=True, prog_bar=True, logger=False)
        return loss_seg.detach()

    @staticmethod
    @torch.no_grad()
    def _train_scalars(step: dict[str, Tensor]) -> dict[str, Tensor]:
        """The logged ``train/*`` scalars from one step's detached values."""
        scalars = {
            "train/loss_seg_src_aux": step["loss_seg_src_aux"],
            "train/loss_seg_src_main": step["loss_seg_src_main"],
        }
        if "loss_adv_trg_aux" in step:
            scalars["train/loss_adv_trg_aux"] = step["loss_adv_trg_aux"]
            scalars["train/loss_adv_trg_main"] = step["loss_adv_trg_main"]
        if "d_src_aux" in step:
            for head in ("aux", "main"):
                scalars[f"train/loss_d_{head}"] = (
                    step[f"loss_d_src_{head}"] + step[f"loss_d_trg_{head}"]
                )
                scalars[f"train/d_acc_{head}"] = 0.5 * (
                    domain_accuracy(step[f"d_src_{head}"], SOURCE_LABEL)
                    + domain_accuracy(step[f"d_trg_{head}"], TARGET_LABEL)
                )
        return scalars

    def _logs_this_step(self) -> bool:
        """True when Lightning hands this step's metrics to the loggers: every
        ``trainer.log_every_n_steps`` steps, the step that stops training, every step of a
        ``fast_dev_run`` (the predicate Lightning's own LearningRateMonitor uses)."""
        trainer = self.trainer
        return bool(trainer.fast_dev_run) or trainer._logger_connector.should_update_logs

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> int | None:
        self._step_values = None
        if self.iteration >= self.max_iters:
            self.trainer.should_stop = True
            return -1  # resumed a finished run: skip the rest of the epoch
        return None

    def on_train_batch_end(self, outputs: Any, batch: Any, batch_idx: int) -> None:
        if self.iteration >= self.max_iters:
            self.trainer.should_stop = True
        # Logged here, after should_stop is known, and only on the steps that reach the loggers
        # (the values in between would never be written): each self.log costs ~0.5 ms of
        # Lightning bookkeeping, 8 scalars at every step were ~2% of a demo iteration.
        if self._step_values is not None and self._logs_this_step():
            step, n_src = self._step_values
            self.log_dict(self._train_scalars(step), on_step=True, on_epoch=False, batch_size=n_src)
        self._step_values = None

    # ------------------------------------------------------------------ validation

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        labels = batch["label"]
        logits = upsample(self.segmenter(self._prepare(batch["image"])).main, labels.shape[-2:])
        self.val_confusion.update(logits.argmax(dim=1), labels)

    def on_validation_epoch_end(self) -> None:
        matrix = self.val_confusion.compute()
        self.val_confusion.reset()
        # NaN for a class absent from truth and prediction; nanmean leaves it out of val/mIoU.
        iou = torch.from_numpy(iou_per_class(matrix.cpu().numpy()))
        iou = iou.to(device=matrix.device, dtype=torch.float32)
        self.log_dict({f"val/IoU/{name}": iou[i] for i, name in enumerate(self.class_names)})
        self.log("val/mIoU", torch.nanmean(iou), prog_bar=True)

    # ------------------------------------------------------------------ checkpoints

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["iteration"] = self.iteration

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        if "iteration" not in checkpoint:
            raise UssSlamError("checkpoint has no 'iteration': not written by uss-train")
        self.iteration = int(checkpoint["iteration"])

"""``PreciseBatchNorm``: BatchNorm statistics of the deployment domain before each validation.

A segmenter trained from scratch with unfrozen BatchNorm (the CPU demo) normalises with batch
statistics while it trains and with running averages when it is evaluated or exported. Those
running averages are poor for two reasons, both measured on the demo (README, Training):

- they follow the last ~10 batches of 4 random crops (momentum 0.1), so the validation mIoU of
  consecutive epochs swings by up to 0.1 with the same weights' quality;
- an adapted run updates them from its source and its target forwards alternately, so they
  describe neither domain, while training normalised each domain with its own statistics.

Before each validation (hence in every checkpoint and export) this callback replaces them by the
exact mean / variance over a fixed, evenly spaced set of full training images (``momentum=None``
= cumulative average; Wu & Johnson 2021, "precise BN") of one domain, ``source`` by default and
for every method alike: then a method's gain over source-only is the method's, not that of the
statistics. Target statistics are AdaBN (Li et al. 2016: unlabelled target images, no labels), a
baseline of its own: :func:`adabn` applies it to any segmenter as an evaluation variant, and
``domain: target`` (every method) or ``domain: auto`` (target for the methods that train on
target frames, source for source-only) put them in the checkpoints instead. Weights are
untouched; no random numbers are drawn (training is reproducible with or without it).

With ``model.net.batchnorm=reference`` (AdaptSegNet's / ADVENT's BatchNorm) the callback leaves
the statistics alone: that mode keeps the running averages of its source and target forwards.
"""

from __future__ import annotations

import logging
from collections.abc import Sized
from typing import Literal

import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from torch import nn
from torch.utils.data import Dataset

from uss_slam.core.errors import UssSlamError
from uss_slam.train.methods.base import BATCH_NORM_LAYERS

log = logging.getLogger(__name__)

Domain = Literal["auto", "source", "target"]


def evenly_spaced(count: int, size: int) -> list[int]:
    """``count`` indices spread evenly over ``range(size)`` (all of them when ``count >= size``)."""
    if size <= 0:
        return []
    if count >= size:
        return list(range(size))
    return [(k * size) // count for k in range(count)]


@torch.no_grad()
def recompute_batchnorm(
    net: nn.Module, dataset: Dataset, indices: list[int], batch_size: int
) -> int:
    """Set every BatchNorm's running mean / variance of ``net`` to the cumulative average of
    batch statistics over ``dataset[i]["image"]`` for ``i`` in ``indices`` (batches of
    ``batch_size`` equal-size images). Returns the number of images; 0 leaves ``net`` as it was.
    Train / eval modes and momenta are restored afterwards."""
    layers = [
        m for m in net.modules() if isinstance(m, BATCH_NORM_LAYERS) and m.track_running_stats
    ]
    if not layers or not indices:
        return 0
    saved = [(m, m.training, m.momentum) for m in layers]
    device = next(net.parameters()).device
    try:
        for m in layers:
            m.reset_running_stats()
            m.momentum = None  # cumulative moving average over all batches
            m.train()
        for start in range(0, len(indices), batch_size):
            images = [dataset[i]["image"] for i in indices[start : start + batch_size]]
            shapes = {tuple(im.shape) for im in images}
            if len(shapes) != 1:
                raise UssSlamError(
                    f"precise BatchNorm: images of one batch differ in size ({sorted(shapes)}); "
                    "use equal-size images or batch_size=1"
                )
            net(torch.stack(images).to(device))
    finally:
        for m, training, momentum in saved:
            m.momentum = momentum
            m.train(training)
    return len(indices)


def adabn(net: nn.Module, target: Dataset, images: int = 48, batch_size: int = 4) -> int:
    """AdaBN (Li et al. 2016), the evaluation variant: ``net``'s BatchNorm statistics replaced
    by those of ``images`` evenly spaced unlabelled ``target`` samples (``"image"`` entries), as
    :class:`PreciseBatchNorm` computes them. Returns the number of images used.

    Raises:
        UssSlamError: ``target`` is empty, or ``images`` / ``batch_size`` < 1.
    """
    if images < 1 or batch_size < 1:
        raise UssSlamError(f"AdaBN: images and batch_size must be >= 1, got {images}, {batch_size}")
    if not isinstance(target, Sized) or len(target) == 0:
        raise UssSlamError("AdaBN: the target dataset is empty")
    return recompute_batchnorm(net, target, evenly_spaced(images, len(target)), batch_size)


class PreciseBatchNorm(Callback):
    """Recompute the segmenter's BatchNorm statistics before every validation (see module doc).

    Args:
        source: labelled source images (samples with ``"image"``, evaluation transform).
        target: target frames (same).
        images: how many images (evenly spaced over the dataset) to average over.
        batch_size: images per forward pass (batch statistics per pass, averaged).
        domain: whose statistics: ``source`` (default, every method alike), ``target`` (AdaBN,
            every method alike) or ``auto`` = ``target`` when the module adapts
            (``pl_module.adaptation``), else ``source`` (unequal across methods).
    """

    def __init__(
        self,
        source: Dataset,
        target: Dataset,
        images: int = 48,
        batch_size: int = 4,
        domain: Domain = "source",
    ) -> None:
        if images < 1 or batch_size < 1:
            raise UssSlamError(
                f"precise BatchNorm: images and batch_size must be >= 1, got {images}, {batch_size}"
            )
        if domain not in ("auto", "source", "target"):
            raise UssSlamError(
                f"precise BatchNorm: domain must be auto, source or target, got {domain!r}"
            )
        self.datasets = {"source": source, "target": target}
        self.images = images
        self.batch_size = batch_size
        self.domain = domain

    def chosen_domain(self, pl_module: LightningModule) -> str:
        if self.domain != "auto":
            return self.domain
        return "target" if getattr(pl_module, "adaptation", False) else "source"

    def on_validation_start(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if trainer.sanity_checking:
            return
        domain = self.chosen_domain(pl_module)
        dataset = self.datasets[domain]
        if not isinstance(dataset, Sized) or len(dataset) == 0:
            raise UssSlamError(f"precise BatchNorm: the {domain} dataset is empty")
        net = getattr(pl_module, "segmenter", pl_module)
        if getattr(net, "batchnorm", None) == "reference":
            # The reference code's statistics are the running averages of its source and
            # target forwards; they stay (checkpoint and export keep them).
            log.debug("BatchNorm statistics kept: model.net.batchnorm=reference")
            return
        indices = evenly_spaced(self.images, len(dataset))
        count = recompute_batchnorm(net, dataset, indices, self.batch_size)
        log.debug("BatchNorm statistics recomputed on %d %s images", count, domain)

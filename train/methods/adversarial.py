"""Output-space adversarial adaptation: what AdaptSegNet and ADVENT share.

An :class:`AdversarialMethod` owns what it trains beside the segmenter: the two PatchGAN
discriminators ``d_aux`` / ``d_main`` (one per head), their optimiser factory and the adversarial
loss weights ``λ_adv_aux`` / ``λ_adv_main`` (config: ``model.method.discriminator``,
``model.method.d_optimizer``, ``model.method.lambda_adv_*``). A subclass says only what a
discriminator sees of a head's output (:meth:`AdversarialMethod.target_map` /
:meth:`AdversarialMethod.source_map`).

One iteration (the paper's Algorithm 1, multi-level):

1. source forward, ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)``;
2. target forward, ``L_adv = λ_adv_aux·BCE(D_aux(M_aux), 0) + λ_adv_main·BCE(D_main(M_main), 0)``
   with the discriminators frozen (``M`` the method's map of the logits upsampled to image size;
   0 = "source"); one SGD step of the segmenter on ``L_seg + L_adv``;
3. + 4. discriminators on the detached source (label 0) and target (label 1) maps; one step of
   the discriminators' optimiser.
"""

from __future__ import annotations

import itertools
from abc import abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar, cast

import torch
from torch import Tensor, nn

from uss_slam.core.errors import UssSlamError
from uss_slam.models.deeplab import SegmenterOutput
from uss_slam.train.losses import (
    SOURCE_LABEL,
    TARGET_LABEL,
    domain_accuracy,
    domain_loss,
    upsample,
)
from uss_slam.train.methods.base import (
    DomainPass,
    Method,
    OptimizerFactory,
    StepValues,
    TargetLoss,
    TrainBatch,
    TrainingModule,
    check_finite,
    check_weight,
    frozen,
    segmenter_step,
)


class AdversarialMethod(Method):
    """Two discriminators that tell source from target maps, and a segmenter trained to fool
    them.

    Args:
        discriminator: factory called twice (``d_aux``, ``d_main``), e.g. a Hydra ``_partial_``
            :class:`~uss_slam.models.PatchDiscriminator` with ``in_channels = num_classes``
            (``model.method.discriminator``).
        d_optimizer: the discriminators' optimiser factory taking ``params`` (Adam;
            ``model.method.d_optimizer``); the module adds its poly schedule.
        lambda_adv_aux: weight of the aux head's adversarial loss (the USS-SLAM paper's 0.002).
        lambda_adv_main: weight of the main head's adversarial loss (the paper's 0.01).
    """

    adapts: ClassVar[bool] = True
    trains_discriminators: ClassVar[bool] = True

    def __init__(
        self,
        discriminator: Callable[[], nn.Module],
        d_optimizer: OptimizerFactory,
        lambda_adv_aux: float = 0.002,
        lambda_adv_main: float = 0.01,
    ) -> None:
        super().__init__()
        if not callable(discriminator) or not callable(d_optimizer):
            raise UssSlamError(
                f"model/method={self.name} trains discriminators: model.method.discriminator and "
                "model.method.d_optimizer must be set (a _partial_ network and optimiser)"
            )
        self.lambda_adv_aux = check_weight("model.method.lambda_adv_aux", lambda_adv_aux)
        self.lambda_adv_main = check_weight("model.method.lambda_adv_main", lambda_adv_main)
        self.d_aux = discriminator()
        self.d_main = discriminator()
        self.d_optimizer_factory = d_optimizer
        self.watch = DiscriminatorWatch()

    # ------------------------------------------------------------------ what a method owns

    @property
    def discriminators(self) -> tuple[nn.Module, nn.Module]:
        """``(d_aux, d_main)``."""
        return self.d_aux, self.d_main

    def optimizers(self) -> list[tuple[OptimizerFactory, list[nn.Parameter]]]:
        params = list(itertools.chain(self.d_aux.parameters(), self.d_main.parameters()))
        return [(self.d_optimizer_factory, params)]

    def settings(self) -> dict[str, Any]:
        return {
            "lambda_adv_aux": self.lambda_adv_aux,
            "lambda_adv_main": self.lambda_adv_main,
            "d_optimizer": self.d_optimizer_factory,
        }

    # ------------------------------------------------------------------ the maps

    @abstractmethod
    def target_map(self, logits: Tensor) -> Tensor:
        """What a discriminator sees of target ``(N, C, H, W)`` logits (upsampled to image
        size)."""

    @abstractmethod
    def source_map(self, log_probs: Tensor) -> Tensor:
        """The same map of the detached source log-probabilities the source loss computed."""

    # ------------------------------------------------------------------ one iteration

    def training_step(self, module: TrainingModule, batch: TrainBatch) -> StepValues:
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
                domain_loss(self.d_aux(maps[0]), SOURCE_LABEL),
                domain_loss(self.d_main(maps[1]), SOURCE_LABEL),
                (self.lambda_adv_aux, self.lambda_adv_main),
                keep=maps,
            )

        # (1) + (2): one segmenter step on the source loss and the adversarial loss.
        with frozen(self.d_aux, self.d_main):
            seg = segmenter_step(module, batch["source"], images_trg, adversarial)
        # (3) + (4): the source maps come from the log-softmax the loss already computed.
        term = cast(TargetLoss, seg.target)
        source_maps = (
            self.source_map(seg.source.log_probs[0].detach()),
            self.source_map(seg.source.log_probs[1].detach()),
        )
        step = seg.values
        step.update(self.discriminator_step(module, source_maps, term.keep, seg.batched))
        self.watch.add(step)
        return step

    def discriminator_step(
        self,
        module: TrainingModule,
        source: tuple[Tensor, Tensor],
        target: tuple[Tensor, Tensor],
        batched: bool,
    ) -> StepValues:
        """Steps (3) + (4): ``d_aux`` / ``d_main`` learn to tell the detached source maps
        (label 0) from the target maps (label 1); one step of their optimiser.

        ``source`` and ``target`` are ``(aux, main)`` maps ``(N, C, H, W)`` (detached here).
        Returns the detached losses and discriminator logits (``loss_d_src_aux``,
        ``d_trg_main``, ...) for :func:`discriminator_scalars`.
        """
        opt_d = module.method_optimizer(0)
        opt_d.zero_grad()

        def both(maps: tuple[Tensor, Tensor]) -> tuple[Tensor, Tensor]:
            return self.d_aux(maps[0]), self.d_main(maps[1])

        def losses(logits: tuple[Tensor, Tensor], domain: float, name: str) -> list[Tensor]:
            aux, main = (domain_loss(x, domain) for x in logits)
            check_finite(
                module.iteration, **{f"loss_d_{name}_aux": aux, f"loss_d_{name}_main": main}
            )
            return [aux, main]

        src = (source[0].detach(), source[1].detach())
        trg = (target[0].detach(), target[1].detach())
        with DomainPass(both, src, trg, module.manual_backward, batched) as d:
            logits = {"src": d.source()}
            loss = {"src": losses(logits["src"], SOURCE_LABEL, "src")}
            d.backward(loss["src"][0] + loss["src"][1])
            logits["trg"] = d.target()
            loss["trg"] = losses(logits["trg"], TARGET_LABEL, "trg")
            d.backward(loss["trg"][0] + loss["trg"][1])
        opt_d.step()
        values: StepValues = {}
        for name in ("src", "trg"):
            for i, head in enumerate(("aux", "main")):
                values[f"loss_d_{name}_{head}"] = loss[name][i].detach()
                values[f"d_{name}_{head}"] = logits[name][i].detach()
        return values

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

    def summary(self) -> dict[str, float]:
        return self.watch.summary()

    def extra_repr(self) -> str:
        return (
            f"name={self.name!r}, lambda_adv_aux={self.lambda_adv_aux}, "
            f"lambda_adv_main={self.lambda_adv_main}"
        )


@torch.no_grad()
def discriminator_scalars(step: StepValues) -> dict[str, Tensor]:
    """``train/loss_d_<head>`` (source + target loss) and ``train/d_acc_<head>`` (share of
    patches whose domain the discriminator gets right) from
    :meth:`AdversarialMethod.discriminator_step`'s values."""
    scalars = {}
    for head in ("aux", "main"):
        scalars[f"train/loss_d_{head}"] = step[f"loss_d_src_{head}"] + step[f"loss_d_trg_{head}"]
        scalars[f"train/d_acc_{head}"] = head_accuracy(step, head)
    return scalars


def head_accuracy(step: StepValues, head: str) -> Tensor:
    """Share of ``head``'s discriminator patches that get their domain right, source and
    target weighted alike (0.5 = chance)."""
    return 0.5 * (
        domain_accuracy(step[f"d_src_{head}"], SOURCE_LABEL)
        + domain_accuracy(step[f"d_trg_{head}"], TARGET_LABEL)
    )


CHANCE_BAND = (0.4, 0.6)
"""Domain accuracies in this band are chance: a discriminator there does not tell the domains
apart, and the adversarial term it drives does not act."""
WATCH_BLOCK = 25
"""Iterations per block mean of :class:`DiscriminatorWatch`."""


class DiscriminatorWatch:
    """Did the discriminators ever tell the domains apart? Per head, the mean domain accuracy
    (:func:`discriminator_scalars`' ``d_acc``, 0.5 = chance) over each block of
    :data:`WATCH_BLOCK` iterations since the run started (or resumed). Every iteration adds on
    the device; one transfer per block."""

    def __init__(self) -> None:
        self.blocks: dict[str, list[float]] = {"aux": [], "main": []}
        self._sum: Tensor | None = None
        self._count = 0

    def add(self, step: StepValues) -> None:
        """One iteration's values (``d_src_<head>`` / ``d_trg_<head>`` discriminator logits)."""
        pair = torch.stack([head_accuracy(step, "aux"), head_accuracy(step, "main")])
        self._sum = pair if self._sum is None else self._sum + pair
        self._count += 1
        if self._count == WATCH_BLOCK:
            self._close()

    def _close(self) -> None:
        if self._sum is None or self._count == 0:
            return
        aux, main = (self._sum / self._count).tolist()
        self.blocks["aux"].append(aux)
        self.blocks["main"].append(main)
        self._sum, self._count = None, 0

    def summary(self) -> dict[str, float]:
        """``train/d_acc_<head>_peak`` (largest block mean), ``train/d_acc_<head>_last`` (the
        last block's), ``train/d_at_chance`` (1.0 when every block mean of both heads lies in
        :data:`CHANCE_BAND`, else 0.0); empty before any iteration. A last, shorter block
        counts."""
        self._close()
        if not self.blocks["main"]:
            return {}
        lo, hi = CHANCE_BAND
        out = {}
        for head, means in self.blocks.items():
            out[f"train/d_acc_{head}_peak"] = max(means)
            out[f"train/d_acc_{head}_last"] = means[-1]
        every = [m for means in self.blocks.values() for m in means]
        out["train/d_at_chance"] = float(all(lo <= m <= hi for m in every))
        return out

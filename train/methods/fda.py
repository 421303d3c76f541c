"""FDA: Fourier domain adaptation (Yang & Soatto, CVPR 2020; its code YanchaoYang/FDA).

Each source crop takes the low-frequency amplitude spectrum of a target crop and keeps its own
phase: the source image in the target's "style" (global colour, illumination, sensor tone),
with the source's content and labels. The segmenter learns ``L_seg`` on these crops and, from
``entropy_start`` of the budget on, the Charbonnier-penalised entropy of its target predictions.

One iteration:

1. ``x_s→t = F⁻¹([β-square of |F(x_t)|, the rest of |F(x_s)|] · e^{i∠F(x_s)})`` per source crop
   (in RGB space; target crop ``i mod M`` for source crop ``i``): the low-frequency square of
   side ``⌊β·min(H, W)⌋`` at each corner of the unshifted spectrum, as FDA's
   ``low_freq_mutate``;
2. ``L = λ_seg_aux·CE(aux(x_s→t)) + λ_seg_main·CE(main(x_s→t)) + λ_ent_aux·E(aux(x_t)) +
   λ_ent_main·E(main(x_t))``, with ``E = mean_pixels (ĥ² + 1e-8)^η`` of the per-pixel entropy
   ``ĥ`` normalised by ``log C`` (FDA's ``EntropyLoss``, ``η = 2``); one SGD step.

FDA's defaults: ``β = 0.01`` (its best single band on GTA5 → Cityscapes), ``λ_ent = 0.005`` on
its single output (here the main head; the aux head's weight defaults to 0), the entropy term
switched on after a third of training (50k of its 150k iterations). FDA's multi-band
transfer (three segmenters trained with β = 0.01, 0.05, 0.09, their predictions averaged, then
self-training on the ensemble's pseudo-labels) trains one model per band:
``uss-train -m model/method=fda model.method.beta=0.01,0.05,0.09``.
"""

from __future__ import annotations

from typing import ClassVar

import torch
from torch import Tensor

from uss_slam.core.errors import UssSlamError
from uss_slam.models.deeplab import SegmenterOutput
from uss_slam.train.image_space import from_rgb, to_rgb
from uss_slam.train.losses import normalised_entropy
from uss_slam.train.methods.base import (
    Method,
    StepValues,
    TargetLoss,
    TrainBatch,
    TrainingModule,
    check_weight,
    segmenter_step,
)


def low_frequency_swap(source: Tensor, target: Tensor, beta: float) -> Tensor:
    """``source`` ``(N, 3, H, W)`` images with the low-frequency amplitude of ``target``
    ``(M, 3, H, W)`` (crop ``i mod M`` for source crop ``i``), phase kept; same shape and
    scale as ``source``, float32. ``β`` in (0, 0.5]: the side of each swapped corner square is
    ``⌊β·min(H, W)⌋`` frequencies (none when that is 0)."""
    if source.shape[1:] != target.shape[1:]:
        raise ValueError(
            f"source and target images must have one shape, got {tuple(source.shape[1:])} "
            f"and {tuple(target.shape[1:])}"
        )
    h, w = source.shape[-2:]
    b = int(min(h, w) * beta)
    if b == 0:
        return source.float()
    index = torch.arange(source.shape[0], device=source.device) % target.shape[0]
    spec_src = torch.fft.fft2(source.float())
    amp_trg = torch.fft.fft2(target.float()[index]).abs()
    amp, phase = spec_src.abs(), spec_src.angle()
    for rows in (slice(0, b), slice(h - b, h)):
        for cols in (slice(0, b), slice(w - b, w)):
            amp[..., rows, cols] = amp_trg[..., rows, cols]
    return torch.fft.ifft2(torch.polar(amp, phase)).real


def charbonnier_entropy(logits: Tensor, size: tuple[int, int], eta: float) -> Tensor:
    """FDA's target loss of ``(N, C, h, w)`` logits upsampled to ``size``:
    ``mean((ĥ² + 1e-8)^η)`` of the normalised per-pixel entropy ``ĥ`` (0..1)."""
    return (normalised_entropy(logits, size).pow(2) + 1e-8).pow(eta).mean()


class FDA(Method):
    """``model/method=fda``: segmentation of source crops in the target's low-frequency
    amplitude, plus FDA's entropy penalty on the target.

    Args:
        beta: side of the swapped low-frequency square as a share of ``min(H, W)``, in (0, 0.5]
            (FDA's ``LB``; 0.01, 0.05, 0.09 in its multi-band runs).
        lambda_ent_aux: weight of the aux head's target entropy penalty.
        lambda_ent_main: weight of the main head's (FDA's ``entW`` 0.005 on its one output).
        eta: the penalty's exponent (FDA's ``ita``, 2.0).
        entropy_start: share of ``model.max_iters`` after which the entropy term is on, in
            [0, 1] (FDA's ``switch2entropy``, 50k of 150k iterations).
    """

    name: ClassVar[str] = "fda"
    adapts: ClassVar[bool] = True
    needs_equal_crops: ClassVar[bool] = True

    def __init__(
        self,
        beta: float = 0.01,
        lambda_ent_aux: float = 0.0,
        lambda_ent_main: float = 0.005,
        eta: float = 2.0,
        entropy_start: float = 1 / 3,
    ) -> None:
        super().__init__()
        if isinstance(beta, bool) or not isinstance(beta, (int, float)) or not 0 < beta <= 0.5:
            raise UssSlamError(f"model.method.beta must be in (0, 0.5], got {beta!r}")
        if isinstance(eta, bool) or not isinstance(eta, (int, float)) or not eta > 0:
            raise UssSlamError(f"model.method.eta must be a number > 0, got {eta!r}")
        start = check_weight("model.method.entropy_start", entropy_start)
        if start > 1:
            raise UssSlamError(f"model.method.entropy_start must be in [0, 1], got {start!r}")
        self.beta = float(beta)
        self.lambda_ent_aux = check_weight("model.method.lambda_ent_aux", lambda_ent_aux)
        self.lambda_ent_main = check_weight("model.method.lambda_ent_main", lambda_ent_main)
        self.eta = float(eta)
        self.entropy_start = start

    def settings(self) -> dict[str, float]:
        return {
            "beta": self.beta,
            "lambda_ent_aux": self.lambda_ent_aux,
            "lambda_ent_main": self.lambda_ent_main,
            "eta": self.eta,
            "entropy_start": self.entropy_start,
        }

    def training_step(self, module: TrainingModule, batch: TrainBatch) -> StepValues:
        source, images_trg = batch["source"], batch["target"]["image"]
        if source["image"].shape[1:] != images_trg.shape[1:]:
            raise UssSlamError(
                "model/method=fda swaps spectra of source and target crops: they must have one "
                f"size, got {tuple(source['image'].shape[-2:])} and "
                f"{tuple(images_trg.shape[-2:])} (set data.source.transform.crop_size and "
                "data.target.transform.crop_size alike)"
            )
        with torch.no_grad():
            swapped = low_frequency_swap(to_rgb(source["image"]), to_rgb(images_trg), self.beta)
            styled = from_rgb(swapped).to(source["image"].dtype)
        on = module.iteration >= self.entropy_start * module.max_iters
        weights = (self.lambda_ent_aux, self.lambda_ent_main) if on else (0.0, 0.0)
        size = images_trg.shape[-2:]

        def entropy(pred: SegmenterOutput) -> TargetLoss:
            return TargetLoss(
                "loss_ent_trg",
                "loss_ent",
                charbonnier_entropy(pred.aux, size, self.eta),
                charbonnier_entropy(pred.main, size, self.eta),
                weights,
            )

        return segmenter_step(module, {**source, "image": styled}, images_trg, entropy).values

    def extra_repr(self) -> str:
        return (
            f"name={self.name!r}, beta={self.beta}, lambda_ent_main={self.lambda_ent_main}, "
            f"eta={self.eta}, entropy_start={self.entropy_start:.3g}"
        )

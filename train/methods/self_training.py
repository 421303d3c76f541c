"""Self-training with a mean teacher and ClassMix domain mixing (DACS, Tranheden et al. WACV 2021;
the form of DAFormer / HRDA / MIC, Hoyer et al. CVPR 2022 / ECCV 2022 / CVPR 2023, without their
transformer, multi-resolution and masking parts).

One iteration (DAFormer's ``DACS.forward_train``):

1. teacher update: the teacher's parameters are an exponential moving average of the student's
   (the segmenter), ``θ_t ← a·θ_t + (1 − a)·θ_s`` with ``a = min(1 − 1/(i + 1), alpha)`` at
   iteration ``i`` (a copy of the student at iteration 0, DAFormer's warm-up); as in DACS and
   DAFormer only the parameters are averaged (the BatchNorm buffers are copied from the student,
   see step 3);
2. source forward, ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)`` (``model.loss``);
3. pseudo-labels: the teacher (no gradients) labels the target crops with the argmax of its main
   head, in train mode as DACS (``ema_model.train()``) and DAFormer (only dropout / drop-path
   switched off): a trained BatchNorm normalises with the target batch's own statistics, a
   frozen one (``model.net.freeze_bn``) with the student's running statistics; dropout is off.
   Their weight is the fraction of the batch's pixels whose top probability exceeds
   ``pseudo_threshold`` (one number per batch, as DAFormer);
4. ClassMix: per pair ``i``, half of the classes present in source label ``i`` (``ceil(n/2)`` of
   ``n``, ignore label excluded) are pasted with their pixels onto target crop ``i``; labels
   mixed likewise (source labels inside the mask, pseudo-labels outside), pixel weights 1 inside
   and the pseudo-label weight outside; then DAFormer's strong augmentation of the mixed crops
   (colour jitter, Gaussian blur);
5. mixed forward, ``L_mix = λ_seg_aux·wCE(aux) + λ_seg_main·wCE(main)`` (pixel-weighted
   cross-entropy, mean over labelled pixels); one SGD step of the student on ``L_seg + L_mix``.

No discriminators are built. The student is the segmenter that is
exported; the teacher lives in the method (``method.teacher.*`` in checkpoints, with its update
count) so that a resumed run continues exactly; it is never exported. The random choices of an
iteration (classes, augmentation) come from a generator seeded by ``(seed, rank, iteration)``:
reproducible and the same after a resume.

``rare_class_mixing`` is a mixing-side variant of DAFormer's rare-class sampling (RCS): instead of
sampling *source images* that contain rare classes (which needs the data module), the classes
to paste are drawn with DAFormer's RCS distribution ``P(c) ∝ exp((1 − f_c)/T)`` over the classes
present, ``f_c`` the pixel frequency of class ``c`` in the source labels seen so far (a running
count saved in checkpoints). Rare classes then reach the target crops more often.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.optim.swa_utils import AveragedModel
from torchvision.transforms import v2

from uss_slam.core.classes import IGNORE_INDEX
from uss_slam.core.errors import UssSlamError
from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.models.deeplab import SegmenterOutput
from uss_slam.train.image_space import from_rgb, to_rgb
from uss_slam.train.losses import upsample
from uss_slam.train.methods.base import (
    Method,
    StepValues,
    TargetLoss,
    TrainBatch,
    TrainingModule,
    segmenter_step,
)


def ema_decay(updates: int, alpha: float) -> float:
    """DAFormer's teacher decay after ``updates`` earlier updates: ``min(1 − 1/(updates + 1),
    alpha)`` (0 at the first update: a copy)."""
    return min(1.0 - 1.0 / (updates + 1), alpha)


class _EmaUpdate:
    """``multi_avg_fn`` of :class:`~torch.optim.swa_utils.AveragedModel`: the EMA of the
    parameters with DAFormer's warm-up."""

    def __init__(self, alpha: float) -> None:
        self.alpha = alpha

    @torch.no_grad()
    def __call__(self, averaged: list[Tensor], current: list[Tensor], updates: Tensor) -> None:
        decay = ema_decay(int(updates), self.alpha)
        for a, c in zip(averaged, current, strict=True):
            a.mul_(decay).add_(c, alpha=1.0 - decay)


def class_mix_masks(
    labels: Tensor, class_weights: Tensor | None = None, ignore_index: int = IGNORE_INDEX
) -> Tensor:
    """ClassMix masks: per ``(H, W)`` label map of ``labels`` ``(N, H, W)``, ``ceil(n/2)`` of its
    ``n`` classes (``ignore_index`` excluded) drawn without replacement, uniformly or with
    probabilities proportional to ``class_weights[c]`` (``(C,)``); returns ``(N, H, W)`` bool,
    True on the pixels of the drawn classes. Uses torch's global random generator."""
    masks = torch.zeros(labels.shape, dtype=torch.bool, device=labels.device)
    for i, label in enumerate(labels):
        classes = torch.unique(label)
        classes = classes[classes != ignore_index]
        n = classes.numel()
        if n == 0:
            continue
        k = (n + 1) // 2
        if class_weights is None:
            chosen = classes[torch.randperm(n)[:k].to(classes.device)]
        else:
            weights = class_weights.to(classes.device)[classes].double().cpu()
            chosen = classes[torch.multinomial(weights, k, replacement=False).to(classes.device)]
        masks[i] = torch.isin(label, chosen)
    return masks


def rare_class_weights(class_pixels: Tensor, temperature: float) -> Tensor:
    """DAFormer's RCS distribution ``softmax((1 − f_c) / T)`` of the class frequencies
    ``f_c = class_pixels / sum`` (uniform before any pixel is counted)."""
    total = class_pixels.sum()
    if total <= 0:
        return torch.full_like(class_pixels, 1.0 / class_pixels.numel())
    return torch.softmax((1.0 - class_pixels / total) / temperature, dim=0)


class StrongAugmentation:
    """DACS / DAFormer's strong augmentation of the mixed crops (``strong_transform``): with
    probability ``1 − jitter_probability`` colour jitter of strength ``jitter_strength``
    (brightness, contrast, saturation and hue factors as torchvision's ``ColorJitter(s, s, s,
    s)``), and with probability 0.5 (when ``blur``) a Gaussian blur with a kernel of about a tenth
    of the crop size (odd) and ``σ ~ U(0.15, 1.15)``. Both decisions are drawn once per batch, the
    factors per crop, from torch's global generator. Works on normalised images (denormalised
    with ``mean`` / ``std`` for the jitter, renormalised afterwards)."""

    def __init__(
        self,
        jitter_strength: float = 0.2,
        jitter_probability: float = 0.2,
        blur: bool = True,
        mean: Sequence[float] = IMAGENET_MEAN,
        std: Sequence[float] = IMAGENET_STD,
    ) -> None:
        s = jitter_strength
        self.jitter = v2.ColorJitter(brightness=s, contrast=s, saturation=s, hue=s) if s else None
        self.jitter_probability = jitter_probability
        self.blur = blur
        self.mean = tuple(mean)
        self.std = tuple(std)

    @staticmethod
    def kernel_size(length: int) -> int:
        """DAFormer's blur kernel for a side of ``length`` pixels: ``ceil(0.1·length)`` made odd
        (rounded down when even)."""
        tenth = math.ceil(0.1 * length)
        return max(1, tenth - 1 + tenth % 2)

    def __call__(self, images: Tensor) -> Tensor:
        jitter = self.jitter is not None and float(torch.rand(())) > self.jitter_probability
        blur = self.blur and float(torch.rand(())) > 0.5
        if not (jitter or blur):
            return images
        rgb = to_rgb(images, self.mean, self.std).clamp(0.0, 1.0)
        if blur:
            h, w = images.shape[-2:]
            blurrer = v2.GaussianBlur([self.kernel_size(w), self.kernel_size(h)], (0.15, 1.15))
        out = []
        for image in rgb:
            if jitter:
                image = self.jitter(image)
            if blur:
                image = blurrer(image)
            out.append(image)
        return from_rgb(torch.stack(out), self.mean, self.std)


def iteration_seed(seed: int, rank: int, iteration: int) -> int:
    """A well-mixed 32-bit seed for the random choices of one iteration of one rank."""
    return int(np.random.SeedSequence([seed, rank, iteration]).generate_state(1)[0])


def weighted_segmentation_loss(log_probs: Tensor, labels: Tensor, weights: Tensor) -> Tensor:
    """Pixel-weighted cross-entropy: ``sum(w · CE) / #labelled pixels`` of ``(N, C, H, W)``
    log-probabilities, ``(N, H, W)`` labels and weights; ``IGNORE_INDEX`` pixels excluded."""
    ce = F.nll_loss(log_probs, labels, ignore_index=IGNORE_INDEX, reduction="none")
    return (ce * weights).sum() / (labels != IGNORE_INDEX).sum().clamp(min=1)


class SelfTraining(Method):
    """``model/method=self_training``: mean-teacher pseudo-labels + ClassMix (DACS / DAFormer).

    Args:
        teacher: a network of the segmenter's architecture (the config passes ``${model.net}``);
            its weights are replaced by the student's at the first iteration.
        alpha: EMA decay of the teacher (DAFormer 0.99).
        pseudo_threshold: confidence above which a pseudo-labelled pixel counts towards the
            pseudo-label weight (DAFormer 0.968).
        augment: DAFormer's strong augmentation of the mixed crops (colour jitter, blur).
        jitter_strength: colour-jitter strength ``s`` (DAFormer 0.2).
        jitter_probability: the jitter is skipped with this probability (DAFormer 0.2).
        blur: Gaussian blur with probability 0.5 (DAFormer: on).
        rare_class_mixing: draw the pasted classes with DAFormer's rare-class distribution (see
            the module docstring) instead of uniformly.
        rare_class_temperature: ``T`` of that distribution (DAFormer's RCS 0.01).
        seed: base seed of the per-iteration random choices (the config passes ``${seed}``).
    """

    name: ClassVar[str] = "self_training"
    adapts: ClassVar[bool] = True
    needs_equal_crops: ClassVar[bool] = True

    def __init__(
        self,
        teacher: nn.Module,
        alpha: float = 0.99,
        pseudo_threshold: float = 0.968,
        augment: bool = True,
        jitter_strength: float = 0.2,
        jitter_probability: float = 0.2,
        blur: bool = True,
        rare_class_mixing: bool = False,
        rare_class_temperature: float = 0.01,
        seed: int = 0,
    ) -> None:
        super().__init__()
        _check_range("alpha", alpha, 0.0, 1.0)
        _check_range("pseudo_threshold", pseudo_threshold, 0.0, 1.0)
        _check_range("jitter_strength", jitter_strength, 0.0, 0.5)
        _check_range("jitter_probability", jitter_probability, 0.0, 1.0)
        if isinstance(rare_class_temperature, bool) or not (
            isinstance(rare_class_temperature, (int, float)) and rare_class_temperature > 0
        ):
            raise UssSlamError(
                "model.method.rare_class_temperature must be a number > 0, got "
                f"{rare_class_temperature!r}"
            )
        if not isinstance(teacher, nn.Module):
            raise UssSlamError(
                "model.method.teacher must build a network (the segmenter's config, "
                f"${{model.net}}), got {type(teacher).__name__}"
            )
        num_classes = getattr(teacher, "num_classes", None)
        if not isinstance(num_classes, int):
            raise UssSlamError(
                f"model.method.teacher ({type(teacher).__name__}) has no integer num_classes"
            )
        self.alpha = float(alpha)
        self.pseudo_threshold = float(pseudo_threshold)
        self.rare_class_mixing = bool(rare_class_mixing)
        self.rare_class_temperature = float(rare_class_temperature)
        self.seed = int(seed)
        self.augmentation = (
            StrongAugmentation(jitter_strength, jitter_probability, blur) if augment else None
        )
        self.teacher = AveragedModel(
            teacher, multi_avg_fn=_EmaUpdate(self.alpha), use_buffers=False
        )
        self.teacher.requires_grad_(False)
        self.register_buffer("class_pixels", torch.zeros(num_classes, dtype=torch.float64))

    @torch.no_grad()
    def update_teacher(self, student: nn.Module) -> None:
        """One EMA step of the teacher's parameters towards ``student``'s (a copy at the first
        call); its buffers (BatchNorm running statistics) become the student's: unused by a
        trained BatchNorm in train mode, they are what a frozen one normalises with."""
        self.teacher.update_parameters(student)
        for mine, theirs in zip(self.teacher.module.buffers(), student.buffers(), strict=True):
            mine.copy_(theirs)

    @torch.no_grad()
    def teacher_logits(self, images: Tensor) -> Tensor:
        """The teacher's main-head logits of ``(N, 3, H, W)`` ``images``, upsampled to ``(N, C, H,
        W)``: in train mode (BatchNorm on the batch's statistics unless frozen), dropout off,
        as DACS and DAFormer. (The running statistics this forward moves are reset to the
        student's at the next :meth:`update_teacher`.)"""
        teacher = self.teacher.module
        teacher.train()
        for m in teacher.modules():
            if isinstance(m, nn.modules.dropout._DropoutNd):
                m.eval()
        return upsample(teacher(images).main, images.shape[-2:])

    @torch.no_grad()
    def pseudo_labels(self, images: Tensor) -> tuple[Tensor, Tensor]:
        """The teacher's ``(N, H, W)`` int64 labels of ``images`` (main head, upsampled to image
        size; :meth:`teacher_logits`) and their weight: the fraction of pixels whose top
        probability exceeds ``pseudo_threshold`` (a 0-d tensor)."""
        logits = self.teacher_logits(images)
        confidence, labels = torch.softmax(logits, dim=1).max(dim=1)
        weight = (confidence > self.pseudo_threshold).float().mean()
        return labels, weight

    def training_step(self, module: TrainingModule, batch: TrainBatch) -> StepValues:
        w = module.loss_weights
        images_src, labels_src = batch["source"]["image"], batch["source"]["label"]
        images_trg = batch["target"]["image"]
        if images_src.shape != images_trg.shape:
            raise UssSlamError(
                f"model/method=self_training mixes source and target crops pixel by pixel: "
                f"they must have one shape, got source {tuple(images_src.shape)} and target "
                f"{tuple(images_trg.shape)} (set data.source.transform.crop_size and "
                "data.target.transform.crop_size alike, and the same data.batch_size)"
            )
        # (1) the teacher follows the student (DAFormer: before the iteration's losses).
        self.update_teacher(module.segmenter)
        # (3) + (4) pseudo-labels, masks and augmentation: no gradients, seeded per iteration.
        pseudo, pseudo_weight = self.pseudo_labels(images_trg)
        valid = labels_src[labels_src != IGNORE_INDEX]
        self.class_pixels += torch.bincount(valid, minlength=self.class_pixels.numel())[
            : self.class_pixels.numel()
        ].to(self.class_pixels)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(iteration_seed(self.seed, module.global_rank, module.iteration))
            weights = (
                rare_class_weights(self.class_pixels, self.rare_class_temperature)
                if self.rare_class_mixing
                else None
            )
            mask = class_mix_masks(labels_src, weights)
            mixed = torch.where(mask[:, None], images_src, images_trg)
            if self.augmentation is not None:
                mixed = self.augmentation(mixed)
        if module.channels_last:
            mixed = mixed.contiguous(memory_format=torch.channels_last)
        labels_mix = torch.where(mask, labels_src, pseudo)
        weights_mix = torch.where(mask, torch.ones_like(pseudo_weight), pseudo_weight)

        size = labels_mix.shape[-2:]

        def mixed_loss(pred_mix: SegmenterOutput) -> TargetLoss:
            # (5) pixel-weighted loss on the mixed crops, both heads.
            return TargetLoss(
                "loss_seg_mix",
                "loss_mix",
                weighted_segmentation_loss(
                    F.log_softmax(upsample(pred_mix.aux, size), dim=1), labels_mix, weights_mix
                ),
                weighted_segmentation_loss(
                    F.log_softmax(upsample(pred_mix.main, size), dim=1), labels_mix, weights_mix
                ),
                (w.lambda_seg_aux, w.lambda_seg_main),
            )

        # (2) + (5): one student step on the source loss and the mixed loss.
        step = segmenter_step(module, batch["source"], mixed, mixed_loss).values
        step["pseudo_weight"] = pseudo_weight
        return step

    def extra_repr(self) -> str:
        return (
            f"name={self.name!r}, alpha={self.alpha}, pseudo_threshold={self.pseudo_threshold}, "
            f"augment={self.augmentation is not None}, rare_class_mixing={self.rare_class_mixing}"
        )


def _check_range(key: str, value: object, low: float, high: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
        raise UssSlamError(f"model.method.{key} must be a number in [{low}, {high}], got {value!r}")

"""Losses of the paper's Algorithm 1 (eqs. 3–8) and their weights.

Every loss is a mean over pixels (and batch): the paper's sums over ``h, w`` only rescale the
weights, and the published weights (0.1 / 1.0 / 0.002 / 0.01) are those of mean-reduced losses
(AdaptSegNet / ADVENT).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from uss_slam.core.classes import IGNORE_INDEX
from uss_slam.core.schema import ranged

SOURCE_LABEL = 0.0
"""Domain label of source outputs for the discriminators (paper: 0 = source)."""
TARGET_LABEL = 1.0


@dataclass(frozen=True)
class LossWeights:
    """λ of the source segmentation loss of both heads (paper §3.3 defaults), ``model.loss``;
    every method trains with it. A method's own terms carry their weights on the method
    (``model.method.lambda_adv_*``, ``model.method.lambda_ent_*``)."""

    lambda_seg_aux: float = ranged(0.1, min=0)
    lambda_seg_main: float = ranged(1.0, min=0)


def upsample(logits: Tensor, size: tuple[int, int]) -> Tensor:
    """Bilinear upsampling of ``(N, C, h, w)`` head logits to ``size = (H, W)``, in float32:
    under mixed precision the heads return bfloat16 / float16 logits, and the softmax maps and
    losses computed from them stay float32 (a no-op in full precision).

    ``align_corners=True`` as DeepLab-v2 and its adaptation descendants: an input of ``8k + 1``
    pixels maps its ``k + 1`` logit rows exactly onto pixel rows ``0, 8, ..., 8k``.
    """
    return F.interpolate(logits.float(), size=size, mode="bilinear", align_corners=True)


def segmentation_loss(log_probs: Tensor, labels: Tensor) -> Tensor:
    """Cross-entropy (eq. 3, one head) from ``(N, C, H, W)`` log-probabilities and ``(N, H, W)``
    int64 labels; ``IGNORE_INDEX`` pixels are excluded. Returns 0 when every pixel is ignored.

    The mean over the valid pixels as sum / max(count, 1): the same numbers as ``nll_loss``'s
    mean (bit for bit on CPU, tested), without a host sync to detect the empty case."""
    total = F.nll_loss(log_probs, labels, ignore_index=IGNORE_INDEX, reduction="sum")
    return total / (labels != IGNORE_INDEX).sum().clamp(min=1)


def domain_loss(d_logits: Tensor, domain: float) -> Tensor:
    """Binary cross-entropy of discriminator logits against a constant domain label
    (eqs. 4–8: ``-log D`` for label 1, ``-log(1 - D)`` for label 0), in float32 also when the
    discriminator ran in reduced precision."""
    d_logits = d_logits.float()
    return F.binary_cross_entropy_with_logits(d_logits, torch.full_like(d_logits, domain))


def domain_accuracy(d_logits: Tensor, domain: float) -> Tensor:
    """Share of discriminator patches that classify their domain correctly (logit > 0 = target)."""
    predicted_target = d_logits > 0
    return (predicted_target if domain == TARGET_LABEL else ~predicted_target).float().mean()


def self_information(log_probs: Tensor) -> Tensor:
    """ADVENT's weighted self-information map ``-P·log P / log C`` of ``(N, C, H, W)``
    log-probabilities, same shape, values in ``[0, 1/(e·ln C)]``; its sum over classes is the
    entropy normalised to ``[0, 1]``. From log-probabilities (not ``P + ε``): exact where
    ``P`` underflows (``0·log 0 = 0``)."""
    classes = log_probs.shape[1]
    if classes < 2:
        raise ValueError(f"self-information needs at least 2 classes, got {classes}")
    return -(log_probs.exp() * log_probs) / math.log(classes)


def normalised_entropy(logits: Tensor, size: tuple[int, int]) -> Tensor:
    """Per-pixel entropy normalised by ``log C`` (0..1), ``(N, H, W)``, of the softmax of
    ``(N, C, h, w)`` logits upsampled to ``size = (H, W)``."""
    return self_information(F.log_softmax(upsample(logits, size), dim=1)).sum(dim=1)


def entropy_loss(logits: Tensor, size: tuple[int, int]) -> Tensor:
    """Mean normalised entropy (0..1) of the softmax of ``(N, C, h, w)`` logits upsampled to
    ``size = (H, W)``: ``mean_{n,h,w} sum_c -P log P / log C`` (ADVENT's ``entropy_loss``)."""
    return normalised_entropy(logits, size).mean()

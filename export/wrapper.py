"""The exported graph as a module: uint8 NHWC RGB in, the chosen head's logits and labels out."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from uss_slam.core.errors import UssSlamError
from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.core.onnx_contract import HEADS


class SegmenterExport(nn.Module):
    """The exported graph: uint8 NHWC RGB -> (logits at input size, uint8 labels).

    ``image`` ``(N, H, W, 3)`` uint8 -> float, ``/255``, ``(x - mean) / std`` per RGB channel,
    NCHW -> the chosen head's logits, bilinearly upsampled (``align_corners=True``, as the
    training losses and validation) -> ``logits`` ``(N, C, H, W)`` float32 and
    ``labels = argmax_C(logits)`` ``(N, H, W)`` uint8.

    With ``members`` (an ensemble: FDA's multi-band ensemble of segmenters trained with several
    β) every segmenter's upsampled logits go through a softmax, the probabilities are averaged
    over ``segmenter`` and the members, and ``logits`` is the log of that mean, ``log(1/K ·
    Σ_k softmax(z_k))`` (computed as a log-sum-exp of log-softmaxes): its softmax is the mean
    probability and its argmax the ensemble's label.
    """

    def __init__(
        self,
        segmenter: nn.Module,
        head: str = "main",
        mean: Sequence[float] = IMAGENET_MEAN,
        std: Sequence[float] = IMAGENET_STD,
        members: Sequence[nn.Module] = (),
    ) -> None:
        super().__init__()
        if head not in HEADS:
            raise UssSlamError(f"head must be one of {HEADS}, got {head!r}")
        self.segmenter = segmenter
        self.members = nn.ModuleList(members)
        self.head = head
        # Scaled by 255 so the graph needs one subtraction and one division.
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1) * 255)
        self.register_buffer("std", torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1) * 255)

    def _logits(self, segmenter: nn.Module, x: Tensor) -> Tensor:
        out = getattr(segmenter(x), self.head)
        return F.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=True)

    def forward(self, image: Tensor) -> tuple[Tensor, Tensor]:
        x = image.permute(0, 3, 1, 2).to(torch.float32)
        x = (x - self.mean) / self.std
        logits = self._logits(self.segmenter, x)
        if len(self.members):
            logp = [F.log_softmax(logits, dim=1)]
            logp += [F.log_softmax(self._logits(m, x), dim=1) for m in self.members]
            logits = torch.logsumexp(torch.stack(logp), dim=0) - math.log(len(logp))
        return logits, logits.argmax(dim=1).to(torch.uint8)

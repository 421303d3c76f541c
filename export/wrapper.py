"""The exported graph as a module: uint8 NHWC RGB in, the chosen head's logits and labels out."""

from __future__ import annotations

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
    """

    def __init__(
        self,
        segmenter: nn.Module,
        head: str = "main",
        mean: Sequence[float] = IMAGENET_MEAN,
        std: Sequence[float] = IMAGENET_STD,
    ) -> None:
        super().__init__()
        if head not in HEADS:
            raise UssSlamError(f"head must be one of {HEADS}, got {head!r}")
        self.segmenter = segmenter
        self.head = head
        # Scaled by 255 so the graph needs one subtraction and one division.
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1) * 255)
        self.register_buffer("std", torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1) * 255)

    def forward(self, image: Tensor) -> tuple[Tensor, Tensor]:
        x = image.permute(0, 3, 1, 2).to(torch.float32)
        x = (x - self.mean) / self.std
        out = getattr(self.segmenter(x), self.head)
        logits = F.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=True)
        return logits, logits.argmax(dim=1).to(torch.uint8)

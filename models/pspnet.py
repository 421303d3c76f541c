"""PSPNet (Zhao et al., CVPR 2017) with two heads: ``main`` = pyramid pooling module on layer4 +
classifier, ``aux`` = the paper's auxiliary classifier on layer3 ("res4b22"), on the dilated
ResNet of :mod:`.backbone` (output stride 8, as DeepLab-v2 and the paper).

Same interface as :class:`~uss_slam.models.deeplab.DeepLabV2`: ``net(images)`` returns a
:class:`~uss_slam.models.deeplab.SegmenterOutput` of logits at ``ceil(H/8) × ceil(W/8)``,
``param_groups(lr, head_lr_mult)`` puts both heads (pyramid pooling included) at the head rate,
so every adaptation method trains it and ``uss-export`` exports it unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from uss_slam.core.errors import UssSlamError
from uss_slam.models.backbone import BackboneName, BatchNormMode, FreezeBatchNorm
from uss_slam.models.deeplab import TwoHeadSegmenter


def _pooling_matrix(length: Tensor | int, bins: int, like: Tensor) -> Tensor:
    """``(bins, length)`` averaging weights of adaptive average pooling along one axis: row ``i``
    averages positions ``floor(i·L/b) .. ceil((i+1)·L/b) − 1`` (PyTorch's bin edges)."""
    index = torch.arange(bins, device=like.device)
    start = torch.div(index * length, bins, rounding_mode="floor")
    end = torch.div((index + 1) * length + bins - 1, bins, rounding_mode="floor")
    position = torch.arange(length, device=like.device)
    inside = (position[None, :] >= start[:, None]) & (position[None, :] < end[:, None])
    weights = inside.to(like.dtype)
    return weights / weights.sum(dim=1, keepdim=True)


def adaptive_avg_pool(x: Tensor, bins: int) -> Tensor:
    """``F.adaptive_avg_pool2d(x, bins)`` of ``(N, C, H, W)`` features as two small matrix
    products: the same numbers, and an ONNX graph that pools any input size (torch's ONNX
    exporter fixes ``adaptive_avg_pool2d``'s kernel to the traced size, or refuses)."""
    rows = _pooling_matrix(x.shape[-2], bins, x)
    cols = _pooling_matrix(x.shape[-1], bins, x)
    return torch.matmul(torch.matmul(rows, x), cols.transpose(0, 1))


def _conv_bn_relu(in_channels: int, out_channels: int, kernel_size: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size, padding=kernel_size // 2, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


class PyramidPooling(nn.Module):
    """The pyramid pooling module: per bin size ``b``, adaptive average pooling to ``b × b``, a
    1×1 conv to ``in_channels / len(bins)`` channels + BN + ReLU, bilinear upsampling back
    (``align_corners=True``); the input and every level concatenated along the channels
    (``2 × in_channels`` for four bins)."""

    def __init__(self, in_channels: int, bins: Sequence[int] = (1, 2, 3, 6)) -> None:
        super().__init__()
        if not bins or any(isinstance(b, bool) or not isinstance(b, int) or b < 1 for b in bins):
            raise UssSlamError(f"pyramid pooling bins must be integers >= 1, got {list(bins)}")
        self.bins = tuple(bins)
        reduced = in_channels // len(self.bins)
        self.stages = nn.ModuleList(_conv_bn_relu(in_channels, reduced, 1) for _ in self.bins)
        self.out_channels = in_channels + reduced * len(self.bins)

    def forward(self, x: Tensor) -> Tensor:
        size = x.shape[-2:]
        levels = [x]
        for bins, stage in zip(self.bins, self.stages, strict=True):
            pooled = stage(adaptive_avg_pool(x, bins))
            levels.append(F.interpolate(pooled, size=size, mode="bilinear", align_corners=True))
        return torch.cat(levels, dim=1)


class PSPHead(nn.Module):
    """Classifier of both PSPNet heads: [pyramid pooling] → 3×3 conv + BN + ReLU → dropout →
    1×1 conv to class logits (``classifier``)."""

    def __init__(
        self,
        in_channels: int,
        num_classes: int,
        mid_channels: int,
        dropout: float,
        bins: Sequence[int] | None = None,
    ) -> None:
        super().__init__()
        self.ppm = PyramidPooling(in_channels, bins) if bins is not None else None
        features = self.ppm.out_channels if self.ppm is not None else in_channels
        self.bottleneck = _conv_bn_relu(features, mid_channels, 3)
        self.dropout = nn.Dropout2d(dropout)
        self.classifier = nn.Conv2d(mid_channels, num_classes, kernel_size=1)

    def forward(self, x: Tensor) -> Tensor:
        if self.ppm is not None:
            x = self.ppm(x)
        return self.classifier(self.dropout(self.bottleneck(x)))


class PSPNet(TwoHeadSegmenter):
    """PSPNet segmenter (output stride 8) with ``aux`` / ``main`` heads.

    Args:
        num_classes: output classes (the project's 4 by default).
        backbone: ``resnet101`` (the paper's), ``resnet50`` or ``resnet_small`` (CI / CPU).
        bins: pyramid pooling bin sizes (the paper's 1, 2, 3, 6).
        dropout: dropout rate before both classifiers (the paper's 0.1).
        batchnorm: ``frozen``: every BatchNorm in eval mode with frozen affine terms, the heads'
            too (their 1×1 pyramid level has one value per channel and image: no batch
            statistics at batch size 1); ``trained`` trains them (needs batch size ≥ 2);
            ``auto`` (default) freezes them exactly when pretrained weights are loaded (a
            randomly initialised frozen BatchNorm stays the identity). ``reference`` (the
            DeepLab-v2 reference code's) is not supported.
        allow_random_init: ``False`` refuses a ResNet-50/101 without weights.
        freeze_bn: the former switch (``True`` = ``frozen``, ``False`` = ``trained``).
        backbone_weights: torchvision weight enum member for the backbone (downloads unless
            cached); ``None``: random initialisation.
        weights_path: local file to initialise from (a PSPNet state dict or ``uss-train``
            checkpoint, or a torchvision ResNet state dict); see
            :func:`~uss_slam.models.weights.load_segmenter_weights`.

    Head widths follow the paper's ResNet-101 network: pyramid levels of ``C4 / 4`` channels
    (512), main 3×3 conv ``C4 / 4`` (512), aux 3×3 conv ``C3 / 4`` (256); the small backbone
    scales them down alike. The paper weights the auxiliary loss 0.4 (``model.loss.lambda_seg_aux``,
    0.1 by default, as the adaptation papers).
    """

    BATCHNORM_SUPPORTED = ("auto", "trained", "frozen")

    def __init__(
        self,
        num_classes: int = 4,
        backbone: BackboneName = "resnet101",
        *,
        bins: Sequence[int] = (1, 2, 3, 6),
        dropout: float = 0.1,
        batchnorm: BatchNormMode = "auto",
        backbone_weights: str | None = None,
        weights_path: str | Path | None = None,
        allow_random_init: bool = True,
        freeze_bn: FreezeBatchNorm | None = None,
    ) -> None:
        if (
            isinstance(dropout, bool)
            or not isinstance(dropout, (int, float))
            or not 0 <= dropout < 1
        ):
            raise UssSlamError(f"model.net.dropout must be a number in [0, 1), got {dropout!r}")
        super().__init__(
            num_classes,
            backbone,
            batchnorm,
            backbone_weights,
            weights_path,
            allow_random_init,
            freeze_bn,
        )
        low, high = self.backbone.out_channels
        self.aux = PSPHead(low, num_classes, low // 4, dropout)
        self.main = PSPHead(high, num_classes, high // 4, dropout, bins=tuple(bins))
        self.finish_init()

    def batchnorm_frozen(self) -> nn.Module:
        return self  # the heads' BatchNorms too (see ``freeze_bn``)

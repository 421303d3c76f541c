"""DeepLab-v2 with two heads: ``aux`` on layer3 (the paper's low-level output) and ``main`` on
layer4 (high-level), each an ASPP classifier summing four dilated 3×3 convolutions."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

from torch import Tensor, nn

from uss_slam.core.errors import UssSlamError
from uss_slam.models.backbone import (
    BATCHNORM_MODES,
    BackboneName,
    BatchNormMode,
    FreezeBatchNorm,
    batchnorm_from_freeze_bn,
    build_backbone,
    freeze_batchnorm,
    freeze_batchnorm_affine,
    resolve_batchnorm,
)

log = logging.getLogger(__name__)


class SegmenterOutput(NamedTuple):
    """Logits of the two heads, each ``(N, num_classes, ceil(H/8), ceil(W/8))``."""

    aux: Tensor
    main: Tensor


class TwoHeadSegmenter(nn.Module):
    """What both segmenters share: a dilated ResNet backbone (:func:`build_backbone`, returning
    layer3 / layer4 features) under an ``aux`` and a ``main`` head.

    Subclasses call ``super().__init__(...)`` (which reads ``weights_path``, if any, and builds
    the backbone in that file's layout), create ``self.aux`` and ``self.main`` from
    ``self.backbone.out_channels``, then :meth:`finish_init`; they name in
    :meth:`batchnorm_frozen` which BatchNorms the ``frozen`` / ``reference`` modes cover and in
    ``BATCHNORM_SUPPORTED`` the modes they support.
    """

    aux: nn.Module
    main: nn.Module
    BATCHNORM_SUPPORTED: tuple[str, ...] = BATCHNORM_MODES

    def __init__(
        self,
        num_classes: int,
        backbone: str,
        batchnorm: BatchNormMode,
        backbone_weights: str | None,
        weights_path: str | Path | None,
        allow_random_init: bool = True,
        freeze_bn: FreezeBatchNorm | None = None,
    ) -> None:
        super().__init__()
        from uss_slam.models.weights import read_weights

        self.num_classes = num_classes
        self.backbone_name = backbone
        pretrained = backbone_weights is not None or weights_path is not None
        if not pretrained and backbone != "resnet_small":
            if not allow_random_init:
                raise UssSlamError(
                    f"model.net.weights_path: not set, and {backbone} from random weights is "
                    "refused here; give a local DeepLab-v2 Caffe init (AdaptSegNet / ADVENT), a "
                    "torchvision ResNet state dict or a uss-train checkpoint, or set "
                    "model.net.allow_random_init=true"
                )
            log.warning(
                "%s starts from random weights (no model.net.weights_path / backbone_weights)",
                backbone,
            )
        self.batchnorm = resolve_batchnorm(
            batchnorm_from_freeze_bn(freeze_bn, batchnorm), pretrained, self.BATCHNORM_SUPPORTED
        )
        # Read before the backbone is built: its layout (where blocks stride) is the file's.
        self._weights = read_weights(weights_path) if weights_path is not None else None
        layout = self._weights.layout if self._weights is not None else "torchvision"
        self.backbone = build_backbone(backbone, backbone_weights, layout)

    @property
    def freeze_bn(self) -> bool:
        """True in the ``frozen`` BatchNorm mode (the former ``freeze_bn`` switch)."""
        return self.batchnorm == "frozen"

    def batchnorm_frozen(self) -> nn.Module:
        """The part whose BatchNorms the ``frozen`` and ``reference`` modes cover."""
        raise NotImplementedError

    def finish_init(self, weights_path: str | Path | None = None) -> None:
        """Apply the BatchNorm mode, then load the weights file read at construction (if any)."""
        self._apply_batchnorm_mode()
        if self._weights is not None:
            from uss_slam.models.weights import load_segmenter_weights

            load_segmenter_weights(self, self._weights)
        self._weights = None  # do not keep a second copy of the file's tensors

    def _apply_batchnorm_mode(self) -> None:
        if self.batchnorm == "frozen":
            freeze_batchnorm(self.batchnorm_frozen())
        elif self.batchnorm == "reference":
            freeze_batchnorm_affine(self.batchnorm_frozen())

    def forward(self, images: Tensor) -> SegmenterOutput:
        low, high = self.backbone(images)
        return SegmenterOutput(aux=self.aux(low), main=self.main(high))

    def train(self, mode: bool = True) -> TwoHeadSegmenter:
        super().train(mode)
        if self.batchnorm == "frozen":
            freeze_batchnorm(self.batchnorm_frozen())
        return self

    def heads(self) -> nn.ModuleDict:
        """The two heads (what is re-initialised when the class count changes, trained at the
        head rate)."""
        return nn.ModuleDict({"aux": self.aux, "main": self.main})

    def param_groups(self, lr: float, head_lr_mult: float = 10.0) -> list[dict[str, Any]]:
        """Optimiser parameter groups: trainable backbone parameters at ``lr``, both heads at
        ``head_lr_mult × lr``. Every trainable parameter appears exactly once."""
        backbone = [p for p in self.backbone.parameters() if p.requires_grad]
        heads = [p for p in self.heads().parameters() if p.requires_grad]
        return [
            {"name": "backbone", "params": backbone, "lr": lr},
            {"name": "heads", "params": heads, "lr": lr * head_lr_mult},
        ]


class ASPPClassifier(nn.Module):
    """Atrous spatial pyramid pooling classifier of DeepLab-v2: the **sum** of one 3×3 conv per
    rate (all four of them), each mapping features straight to class logits."""

    def __init__(
        self, in_channels: int, num_classes: int, rates: Sequence[int] = (6, 12, 18, 24)
    ) -> None:
        super().__init__()
        if not rates:
            raise ValueError("ASPP needs at least one rate")
        self.branches = nn.ModuleList(
            nn.Conv2d(in_channels, num_classes, kernel_size=3, padding=r, dilation=r, bias=True)
            for r in rates
        )
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # DeepLab-v2's initialisation of the classifier: N(0, 0.01), zero bias.
        for conv in self.branches:
            nn.init.normal_(conv.weight, 0.0, 0.01)
            nn.init.zeros_(conv.bias)

    def forward(self, x: Tensor) -> Tensor:
        out = self.branches[0](x)
        for conv in self.branches[1:]:
            out = out + conv(x)
        return out


class DeepLabV2(TwoHeadSegmenter):
    """DeepLab-v2 segmenter (output stride 8, no CRF, single scale) with ``aux``/``main`` heads.

    Args:
        num_classes: number of output classes (the project's 4 by default).
        backbone: ``resnet101`` (paper), ``resnet50`` or ``resnet_small`` (CI / CPU demo).
        aspp_rates: dilation rates of the ASPP branches of both heads.
        batchnorm: what the backbone's BatchNorms do in training (``model.net.batchnorm``):
            ``trained``, ``frozen``, ``reference`` (AdaptSegNet's / ADVENT's) or ``auto``
            (default: ``frozen`` with loaded weights, else ``trained``); see
            :data:`~uss_slam.models.backbone.BATCHNORM_MODES`. The resolved mode is
            ``self.batchnorm``.
        backbone_weights: torchvision weight enum member (``"IMAGENET1K_V1"``, ``"DEFAULT"``)
            for the backbone; downloads unless cached. ``None``: random initialisation.
        weights_path: local file to initialise from (a DeepLabV2 state dict, a training
            checkpoint, a torchvision ResNet state dict or DeepLab-v2's Caffe init, which
            builds the ``caffe`` backbone layout); see :mod:`uss_slam.models.weights`.
        allow_random_init: ``False`` refuses a ResNet-50/101 without weights (one error line);
            ``True`` (default) starts it from random weights with a warning.
        freeze_bn: the former switch (``True`` = ``batchnorm="frozen"``, ``False`` =
            ``"trained"``), kept for Python callers; configs set ``batchnorm``.

    ``forward(images)`` takes ``(N, 3, H, W)`` normalised RGB and returns a
    :class:`SegmenterOutput` of logits at ``ceil(H/8) × ceil(W/8)``, in train and eval mode alike.
    """

    def __init__(
        self,
        num_classes: int = 4,
        backbone: BackboneName = "resnet101",
        *,
        aspp_rates: Sequence[int] = (6, 12, 18, 24),
        batchnorm: BatchNormMode = "auto",
        backbone_weights: str | None = None,
        weights_path: str | Path | None = None,
        allow_random_init: bool = True,
        freeze_bn: FreezeBatchNorm | None = None,
    ) -> None:
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
        self.aux = ASPPClassifier(low, num_classes, aspp_rates)
        self.main = ASPPClassifier(high, num_classes, aspp_rates)
        self.finish_init()

    def batchnorm_frozen(self) -> nn.Module:
        return self.backbone


def output_size(height: int, width: int) -> tuple[int, int]:
    """Spatial size of the logits for an ``height × width`` input (three ceil-halvings)."""
    for _ in range(3):
        height, width = (height + 1) // 2, (width + 1) // 2
    return height, width

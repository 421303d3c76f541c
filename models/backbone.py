"""ResNet backbones at output stride 8 (DeepLab-v2): layer3 dilated by 2, layer4 by 4.

Three backbones share one structure (stem ``conv1 bn1 relu maxpool``, stages ``layer1..layer4``
of torchvision ``Bottleneck`` blocks) and torchvision's parameter names, so a torchvision
ResNet state dict loads into them unchanged:

- ``resnet101`` / ``resnet50``: torchvision's models (optionally with its ImageNet weights);
- ``resnet_small``: a narrow one-block-per-stage ResNet for CI and the CPU demo.

Two layouts of the same parameters (``layout``): ``torchvision`` puts the stride of a
downsampling block on its 3×3 convolution (``conv2``); ``caffe`` (DeepLab-v2's Caffe ResNet, the
network of the COCO-pretrained init that AdaptSegNet and ADVENT start from) puts it on the first
1×1 convolution (``conv1``) and rounds the max-pool's output size up (``ceil_mode``). Same tensor
shapes, other functions: weights trained in one layout are only right in that layout, so a
``caffe`` backbone carries the buffer ``caffe_layout`` in its state dict.

BatchNorm modes (``model.net.batchnorm``, :data:`BATCHNORM_MODES`) are applied by
:func:`apply_batchnorm_mode`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal, get_args

import torch
import torchvision
from torch import Tensor, nn
from torchvision.models.resnet import Bottleneck

from uss_slam.core.errors import UssSlamError

log = logging.getLogger(__name__)

BackboneName = Literal["resnet101", "resnet50", "resnet_small"]
"""The backbones a network's ``backbone`` key takes (the schema's choices: ``model.net.backbone``
names them in its line)."""
BACKBONES: tuple[str, ...] = get_args(BackboneName)

_TORCHVISION_WEIGHTS = {"resnet101": "ResNet101_Weights", "resnet50": "ResNet50_Weights"}

Layout = Literal["torchvision", "caffe"]
LAYOUTS: tuple[str, ...] = ("torchvision", "caffe")
CAFFE_LAYOUT_BUFFER = "caffe_layout"
"""Name of the buffer that marks a ``caffe`` backbone (``backbone.caffe_layout`` in a
segmenter's state dict)."""


@dataclass(frozen=True)
class _SmallSpec:
    stem_width: int = 16
    planes: tuple[int, int, int, int] = (8, 16, 32, 64)  # Bottleneck outputs 4x these
    blocks: tuple[int, int, int, int] = (1, 1, 1, 1)


class ResNetBackbone(nn.Module):
    """A ResNet trunk without pooling/classifier, output stride 8.

    ``forward(x)`` takes ``(N, 3, H, W)`` and returns ``(layer3, layer4)`` features, both of
    spatial size ``ceil(H / 8) × ceil(W / 8)``, with ``out_channels`` channels.
    """

    def __init__(
        self, trunk: torchvision.models.ResNet | _SmallTrunk, layout: Layout = "torchvision"
    ) -> None:
        super().__init__()
        self.conv1 = trunk.conv1
        self.bn1 = trunk.bn1
        self.relu = trunk.relu
        self.maxpool = trunk.maxpool
        self.layer1 = trunk.layer1
        self.layer2 = trunk.layer2
        self.layer3 = trunk.layer3
        self.layer4 = trunk.layer4
        self.layout = layout
        _dilate(self.layer3, 2)
        _dilate(self.layer4, 4)
        if layout == "caffe":
            self.to_caffe_layout()
        self.out_channels: tuple[int, int] = (
            self.layer3[-1].conv3.out_channels,
            self.layer4[-1].conv3.out_channels,
        )

    def to_caffe_layout(self) -> None:
        """Switch to the ``caffe`` layout (same parameters, strides moved; marker buffer)."""
        _caffe_strides(self)
        self.layout = "caffe"
        if not hasattr(self, CAFFE_LAYOUT_BUFFER):
            device = self.conv1.weight.device
            marker = torch.ones((), dtype=torch.uint8, device=device)
            self.register_buffer(CAFFE_LAYOUT_BUFFER, marker)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):  # type: ignore[no-untyped-def]
        # A state dict of a caffe-layout backbone (e.g. a checkpoint that export rebuilds from
        # its net config) turns this backbone into that layout: its weights mean that function.
        if prefix + CAFFE_LAYOUT_BUFFER in state_dict and self.layout != "caffe":
            self.to_caffe_layout()
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        c3 = self.layer3(self.layer2(self.layer1(x)))
        return c3, self.layer4(c3)


def _dilate(stage: nn.Sequential, dilation: int) -> None:
    """Turn a stride-2 stage into a stride-1 stage whose every 3×3 conv has ``dilation``.

    DeepLab-v2 dilates *all* blocks of the stage (torchvision's ``replace_stride_with_dilation``
    keeps the first block of each stage at the previous rate, which is a different network).
    """
    for block in stage:
        block.conv1.stride = (1, 1)  # the caffe layout's stride
        block.conv2.stride = (1, 1)
        block.conv2.dilation = (dilation, dilation)
        block.conv2.padding = (dilation, dilation)
        if block.downsample is not None:
            block.downsample[0].stride = (1, 1)


def _caffe_strides(backbone: ResNetBackbone) -> None:
    """DeepLab-v2's Caffe ResNet: each downsampling block strides in its first 1×1 conv instead
    of its 3×3 conv, and the stem's max-pool rounds up (``ceil_mode=True``), as in AdaptSegNet's
    and ADVENT's ``model/deeplab*.py``."""
    backbone.maxpool.ceil_mode = True
    for stage in (backbone.layer1, backbone.layer2, backbone.layer3, backbone.layer4):
        for block in stage:
            if block.conv2.stride != (1, 1):
                block.conv1.stride, block.conv2.stride = block.conv2.stride, (1, 1)


class _SmallTrunk(nn.Module):
    """Same layout and parameter names as torchvision's ResNet, narrower and shallower."""

    def __init__(self, spec: _SmallSpec) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(3, spec.stem_width, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(spec.stem_width)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        inplanes = spec.stem_width
        stages = []
        for index, (planes, blocks) in enumerate(zip(spec.planes, spec.blocks, strict=True)):
            stride = 1 if index == 0 else 2
            downsample = nn.Sequential(
                nn.Conv2d(inplanes, planes * 4, kernel_size=1, stride=stride, bias=False),
                nn.BatchNorm2d(planes * 4),
            )
            layers = [Bottleneck(inplanes, planes, stride, downsample)]
            inplanes = planes * 4
            layers += [Bottleneck(inplanes, planes) for _ in range(1, blocks)]
            stages.append(nn.Sequential(*layers))
        self.layer1, self.layer2, self.layer3, self.layer4 = stages
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")


def build_backbone(
    name: str, imagenet_weights: str | None = None, layout: Layout = "torchvision"
) -> ResNetBackbone:
    """Build a backbone by name (see :data:`BACKBONES`) in ``layout`` (see the module doc).

    ``imagenet_weights`` names a torchvision weight enum member of that architecture, e.g.
    ``"IMAGENET1K_V1"`` or ``"DEFAULT"``: torchvision downloads it into ``$TORCH_HOME`` unless
    it is cached there. ``None`` (default) = random initialisation, no network access.
    """
    if name not in BACKBONES:
        raise UssSlamError(f"unknown backbone {name!r}; expected one of {', '.join(BACKBONES)}")
    if layout not in LAYOUTS:
        raise UssSlamError(f"unknown backbone layout {layout!r}; expected one of {LAYOUTS}")
    if name == "resnet_small":
        if imagenet_weights is not None:
            raise UssSlamError("resnet_small has no ImageNet weights; set backbone_weights=null")
        return ResNetBackbone(_SmallTrunk(_SmallSpec()), layout)
    weights = None
    if imagenet_weights is not None:
        enum_name = f"{_TORCHVISION_WEIGHTS[name]}.{imagenet_weights}"
        try:
            weights = torchvision.models.get_weight(enum_name)
        except (ValueError, KeyError, AttributeError) as error:
            raise UssSlamError(f"unknown torchvision weights {enum_name!r}: {error}") from error
    constructor = getattr(torchvision.models, name)
    try:
        trunk = constructor(weights=weights)
    except (OSError, RuntimeError) as error:  # URLError is an OSError
        raise UssSlamError(
            f"could not load torchvision weights {weights} ({error}); on a machine without "
            "internet put the file into $TORCH_HOME/hub/checkpoints or pass a local file "
            "with model.net.weights_path"
        ) from error
    if weights is not None:
        log.info("backbone %s initialised from torchvision %s", name, weights)
    return ResNetBackbone(trunk, layout)


BatchNormMode = Literal["auto", "trained", "frozen", "reference"]
BATCHNORM_MODES: tuple[str, ...] = ("auto", "trained", "frozen", "reference")
"""``model.net.batchnorm``, what the BatchNorm layers of a segmenter do while it trains:

- ``trained``: train mode, affine terms learnt, running statistics updated by every training
  forward; each forward is normalised by its own batch (how the target batch is normalised is
  ``model.domain_batch_norm``: by default its own statistics, one forward per domain);
- ``frozen``: eval mode, normalised by the loaded running statistics, which never change;
  affine terms frozen;
- ``reference``: AdaptSegNet's and ADVENT's: train mode (each forward, source and target
  apart, normalised by its own batch; the running statistics updated by both and kept in the
  checkpoint and the export), affine terms frozen (``requires_grad=False``);
- ``auto``: ``frozen`` when pretrained weights are loaded, else ``trained`` (a randomly
  initialised frozen BatchNorm is the identity).
"""


def freeze_batchnorm(module: nn.Module) -> None:
    """Put every BatchNorm of ``module`` in eval mode and stop gradients to its affine terms."""
    for child in module.modules():
        if isinstance(child, nn.modules.batchnorm._BatchNorm):
            child.eval()
            for param in child.parameters():
                param.requires_grad_(False)


def freeze_batchnorm_affine(module: nn.Module) -> None:
    """Stop gradients to the affine terms of every BatchNorm of ``module``; modes stay as they
    are (``reference``: train mode, batch statistics, running statistics updated)."""
    for child in module.modules():
        if isinstance(child, nn.modules.batchnorm._BatchNorm):
            for param in child.parameters():
                param.requires_grad_(False)


def resolve_batchnorm(
    mode: str, pretrained: bool, supported: tuple[str, ...] = BATCHNORM_MODES
) -> str:
    """The BatchNorm mode to apply (``auto`` resolved; ``pretrained``: weights are loaded).

    Raises:
        UssSlamError: ``mode`` is no mode, or one that this network does not support.
    """
    if mode not in BATCHNORM_MODES:
        raise UssSlamError(
            f"model.net.batchnorm must be one of {', '.join(BATCHNORM_MODES)}, got {mode!r}"
        )
    if mode not in supported:
        raise UssSlamError(
            f"model.net.batchnorm={mode} is not supported by this network; supported: "
            f"{', '.join(supported)}"
        )
    if mode == "auto":
        return "frozen" if pretrained else "trained"
    if mode == "frozen" and not pretrained:
        log.warning(
            "model.net.batchnorm=frozen without pretrained weights (backbone_weights / "
            "weights_path): every BatchNorm stays the identity of its initialisation"
        )
    return mode


FreezeBatchNorm = bool | Literal["auto"]
"""The former ``freeze_bn`` argument: ``True`` = ``batchnorm="frozen"``, ``False`` =
``"trained"``, ``"auto"`` = ``"auto"``."""


def batchnorm_from_freeze_bn(freeze_bn: FreezeBatchNorm | None, batchnorm: str) -> str:
    """``batchnorm``, or the mode that the former ``freeze_bn`` argument names (Python callers).

    Raises:
        UssSlamError: ``freeze_bn`` is none of ``True``, ``False``, ``"auto"``, or contradicts
            an explicit ``batchnorm``.
    """
    if freeze_bn is None:
        return batchnorm
    if freeze_bn not in (True, False, "auto") or not isinstance(freeze_bn, bool | str):
        raise UssSlamError(f"freeze_bn must be true, false or auto, got {freeze_bn!r}")
    mode = {True: "frozen", False: "trained", "auto": "auto"}[freeze_bn]
    if batchnorm not in ("auto", mode):
        raise UssSlamError(
            f"freeze_bn={freeze_bn} contradicts model.net.batchnorm={batchnorm}; set only "
            "model.net.batchnorm"
        )
    return mode

"""Initialising a :class:`~uss_slam.models.deeplab.DeepLabV2` or
:class:`~uss_slam.models.pspnet.PSPNet` from a local file (never downloads).

Accepted layouts (read with ``torch.load(weights_only=True)``, never executing pickled code):

- ``checkpoint``: a training checkpoint of ``uss-train`` (``state_dict`` with ``segmenter.*``);
- ``segmenter``: a segmenter state dict (``backbone.* aux.* main.*``);
- ``torchvision``: a torchvision ResNet-50/101 state dict (``conv1.weight``,
  ``layer1.0.conv1.weight``, ...; ``fc.*`` ignored): backbone only;
- ``deeplab-caffe``: DeepLab-v2's Caffe ResNet-101 init, as AdaptSegNet (COCO-pretrained,
  ``DeepLab_resnet_pretrained_init-f81d91e8.pth``) and ADVENT
  (``DeepLab_resnet_pretrained_imagenet.pth``) load it: ``Scale.conv1.weight``, ``Scale.bn1.*``,
  ``Scale.layer1.0.conv1.weight``, ..., and its ASPP classifier ``Scale.layer5.conv2d_list.{0..3}``
  on layer4, which becomes the ``main`` head. That network strides in the first 1×1 conv of a
  block: the segmenter is built with the ``caffe`` backbone layout for it
  (:func:`~uss_slam.models.backbone.build_backbone`). Its first conv expects Caffe's input (BGR,
  0-255, mean subtracted); it is converted to this project's (RGB, ImageNet mean / std).

A file whose heads have another class count (e.g. a 21-class VOC model) loads its backbone, keeps
the freshly initialised heads, and says so in the log and in the returned :class:`LoadReport`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor, nn

from uss_slam.core.errors import DataFormatError
from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.models.backbone import CAFFE_LAYOUT_BUFFER
from uss_slam.models.checkpoint import HEAD_WEIGHTS

log = logging.getLogger(__name__)

_HEAD_PREFIXES = ("aux.", "main.")

ACCEPTED = (
    "a uss-train checkpoint (state_dict with segmenter.*), a segmenter state dict (backbone.*, "
    "aux.*, main.*), a torchvision ResNet-50/101 state dict (conv1.weight, layer1.0.conv1.weight, "
    "fc.*) or DeepLab-v2's Caffe ResNet init of AdaptSegNet / ADVENT (Scale.conv1.weight, "
    "Scale.layer1.0.conv1.weight, Scale.layer5.conv2d_list.*)"
)
"""The layouts :func:`read_weights` accepts, as error messages name them."""

CAFFE_MEAN_BGR = (104.00698793, 116.66876762, 122.67891434)
"""The pixel mean (BGR, 0-255) the Caffe DeepLab-v2 init was trained with (AdaptSegNet's and
ADVENT's ``IMG_MEAN``)."""

_CAFFE_PREFIX = "Scale."
_CAFFE_CLASSIFIER = "Scale.layer5.conv2d_list."


@dataclass(frozen=True)
class LoadReport:
    """What :func:`load_segmenter_weights` did."""

    path: str
    file_format: str  # "checkpoint" | "segmenter" | "torchvision" | "deeplab-caffe"
    backbone_tensors: int
    heads_loaded: bool
    note: str = ""
    ignored_keys: tuple[str, ...] = field(default=())
    layout: str = "torchvision"  # the backbone layout the weights belong to


@dataclass(frozen=True)
class WeightsFile:
    """A weights file read by :func:`read_weights`: tensors under the segmenter's names."""

    path: Path
    state: dict[str, Tensor]
    file_format: str
    layout: str
    """``caffe`` (stride on the first 1×1 conv of a block) or ``torchvision``."""


def _caffe_to_segmenter(state: dict[str, Tensor]) -> dict[str, Tensor]:
    """DeepLab-v2 Caffe names and input convention -> this project's (see the module doc)."""
    out: dict[str, Tensor] = {}
    for key, value in state.items():
        if key.startswith(_CAFFE_CLASSIFIER):
            out["main.branches." + key.removeprefix(_CAFFE_CLASSIFIER)] = value
        elif key.startswith(_CAFFE_PREFIX):
            out["backbone." + key.removeprefix(_CAFFE_PREFIX)] = value
        else:
            out[key] = value  # reported as ignored
    conv1 = out.get("backbone.conv1.weight")
    if conv1 is not None and conv1.ndim == 4 and conv1.shape[1] == 3:
        # Caffe sees x_c = 255 r_c - m_c (BGR); this project r_c = std_c y_c + mean_c (RGB):
        # x_c = 255 std_c y_c + (255 mean_c - m_c). The scale goes into the weights, the
        # constant into bn1's running mean (exact away from the zero-padded border).
        rgb = conv1.flip(1).double()
        std = torch.tensor(IMAGENET_STD, dtype=torch.float64).view(1, 3, 1, 1)
        offset = 255 * torch.tensor(IMAGENET_MEAN, dtype=torch.float64) - torch.tensor(
            CAFFE_MEAN_BGR[::-1], dtype=torch.float64
        )
        out["backbone.conv1.weight"] = (rgb * 255 * std).to(conv1.dtype)
        shift = (rgb.sum(dim=(2, 3)) * offset).sum(dim=1)
        mean = out.get("backbone.bn1.running_mean")
        if mean is not None and mean.shape == shift.shape:
            out["backbone.bn1.running_mean"] = (mean.double() - shift).to(mean.dtype)
    return out


def read_weights(path: str | Path) -> WeightsFile:
    """Read a weights file of one of the accepted layouts (module doc) into segmenter names.

    Raises:
        DataFormatError: naming ``path``: missing, unreadable, or of no accepted layout.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, f"weights file not found; expected {ACCEPTED}")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # unpickling errors have no common base class
        # torch's own text (several paragraphs on weights_only) does not help here
        raise DataFormatError(
            path,
            f"not a readable torch weights file (truncated, corrupt or not written by "
            f"torch.save: {type(error).__name__}); expected {ACCEPTED}",
        ) from error
    if not isinstance(blob, dict):
        raise DataFormatError(
            path, f"expected a dict of tensors, found {type(blob).__name__}; expected {ACCEPTED}"
        )
    if isinstance(blob.get("state_dict"), dict):
        prefixed = {
            k.removeprefix("segmenter."): v
            for k, v in blob["state_dict"].items()
            if k.startswith("segmenter.")
        }
        if not prefixed:
            raise DataFormatError(path, "checkpoint state_dict has no 'segmenter.*' entries")
        state, file_format = prefixed, "checkpoint"
    elif not all(isinstance(v, Tensor) for v in blob.values()):
        raise DataFormatError(path, f"expected a dict of tensors (a state dict): {ACCEPTED}")
    elif "Scale.conv1.weight" in blob:
        state, file_format = _caffe_to_segmenter(blob), "deeplab-caffe"
    elif "conv1.weight" in blob:
        state = {f"backbone.{k}": v for k, v in blob.items() if not k.startswith("fc.")}
        file_format = "torchvision"
    elif "backbone.conv1.weight" in blob:
        state, file_format = dict(blob), "segmenter"
    else:
        first = ", ".join(list(blob)[:3]) or "no keys"
        raise DataFormatError(
            path, f"unknown weights layout (keys {first}, ...); expected {ACCEPTED}"
        )
    caffe = file_format == "deeplab-caffe" or f"backbone.{CAFFE_LAYOUT_BUFFER}" in state
    return WeightsFile(path, state, file_format, "caffe" if caffe else "torchvision")


def load_segmenter_weights(model: nn.Module, weights: str | Path | WeightsFile) -> LoadReport:
    """Copy weights from a file (a path, or one :func:`read_weights` read) into ``model`` (a
    DeepLabV2 or PSPNet); see the module docstring.

    Raises :class:`DataFormatError` naming the file when it is unreadable or of no accepted
    layout, when backbone tensors are missing, when their shapes differ from the model's
    (another architecture), or when its backbone layout (``caffe`` / ``torchvision``) is not
    the model's.
    """
    read = weights if isinstance(weights, WeightsFile) else read_weights(weights)
    path, state, file_format = read.path, read.state, read.file_format
    own = model.state_dict()
    model_layout = getattr(getattr(model, "backbone", None), "layout", "torchvision")
    if read.layout != model_layout:
        raise DataFormatError(
            path,
            f"weights of the {read.layout} backbone layout, the model is built in the "
            f"{model_layout} layout (the stride of a block on another convolution); build it "
            "with model.net.weights_path set to this file",
        )
    marker = f"backbone.{CAFFE_LAYOUT_BUFFER}"

    backbone_keys = [k for k in own if k.startswith("backbone.")]
    missing = [
        k
        for k in backbone_keys
        if k not in state and not k.endswith("num_batches_tracked") and k != marker
    ]
    if missing:
        raise DataFormatError(
            path,
            f"{len(missing)} backbone tensors missing (e.g. {missing[0]!r}) for a "
            f"{getattr(model, 'backbone_name', 'matching')} backbone; expected {ACCEPTED} "
            "of that network",
        )
    extra = [k for k in state if k.startswith("backbone.") and k not in own]
    if extra:
        raise DataFormatError(
            path,
            f"{len(extra)} backbone tensors the model lacks (e.g. {extra[0]!r}): the file does "
            f"not fit model.net.backbone={getattr(model, 'backbone_name', '?')}",
        )
    wrong = [k for k in backbone_keys if k in state and state[k].shape != own[k].shape]
    if wrong:
        key = wrong[0]
        raise DataFormatError(
            path,
            f"backbone tensor {key!r} has shape {tuple(state[key].shape)}, the model expects "
            f"{tuple(own[key].shape)}: the file does not fit model.net.backbone="
            f"{getattr(model, 'backbone_name', '?')}",
        )
    to_load = {k: state[k] for k in backbone_keys if k in state and k != marker}

    head_keys = [k for k in own if k.startswith(_HEAD_PREFIXES)]
    note = ""
    heads_loaded = False
    if file_format == "torchvision":
        note = "torchvision ResNet weights: backbone loaded, heads keep their initialisation"
    elif file_format == "deeplab-caffe" and any(k not in state for k in head_keys):
        main = [k for k in head_keys if k.startswith("main.")]
        if main and all(k in state and state[k].shape == own[k].shape for k in main):
            to_load.update({k: state[k] for k in main})
            note = "DeepLab-v2 Caffe init: backbone and main head loaded, aux head initialised"
        else:
            found = state.get("main.branches.0.weight")
            classes = f"{found.shape[0]}-class " if found is not None else ""
            note = (
                f"DeepLab-v2 Caffe init: backbone loaded, its {classes}classifier does not fit "
                "the model's heads: both heads keep their initialisation"
            )
    elif any(k not in state for k in head_keys):
        note = "file has no (complete) heads: heads keep their initialisation"
    elif any(state[k].shape != own[k].shape for k in head_keys):
        classes = next(k for k in HEAD_WEIGHTS if k in own)
        note = (
            f"file heads have {state[classes].shape[0]} classes, the model has "
            f"{own[classes].shape[0]}: backbone loaded, heads re-initialised"
        )
    else:
        to_load.update({k: state[k] for k in head_keys})
        heads_loaded = True
    if note:
        log.warning("%s: %s", path, note)

    ignored = tuple(sorted(k for k in state if k not in own))
    model.load_state_dict(to_load, strict=False)
    report = LoadReport(
        path=str(path),
        file_format=file_format,
        backbone_tensors=sum(1 for k in to_load if k.startswith("backbone.")),
        heads_loaded=heads_loaded,
        note=note,
        ignored_keys=ignored,
        layout=read.layout,
    )
    log.info(
        "%s: read as %s weights (%s backbone layout): %d backbone tensors%s",
        path,
        file_format,
        read.layout,
        report.backbone_tensors,
        ", heads loaded" if heads_loaded else "",
    )
    return report

"""Initialising a :class:`~uss_slam.models.deeplab.DeepLabV2` or
:class:`~uss_slam.models.pspnet.PSPNet` from a local file.

Accepted files (read with ``torch.load(weights_only=True)``, never executing pickled code):

- a training checkpoint of ``uss-train`` (``state_dict`` with ``segmenter.*`` keys);
- a segmenter state dict (``backbone.* aux.* main.*``);
- a torchvision ResNet state dict (``conv1.* layer1.* ... fc.*``): backbone only.

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
from uss_slam.models.checkpoint import HEAD_WEIGHTS

log = logging.getLogger(__name__)

_HEAD_PREFIXES = ("aux.", "main.")


@dataclass(frozen=True)
class LoadReport:
    """What :func:`load_segmenter_weights` did."""

    path: str
    file_format: str  # "checkpoint" | "segmenter" | "torchvision"
    backbone_tensors: int
    heads_loaded: bool
    note: str = ""
    ignored_keys: tuple[str, ...] = field(default=())


def _read_state_dict(path: Path) -> tuple[dict[str, Tensor], str]:
    if not path.is_file():
        raise DataFormatError(path, "weights file not found")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # unpickling errors have no common base class
        raise DataFormatError(
            path, f"not a readable torch weights file ({type(error).__name__}: {error})"
        ) from error
    if not isinstance(blob, dict):
        raise DataFormatError(path, f"expected a dict of tensors, found {type(blob).__name__}")
    if isinstance(blob.get("state_dict"), dict):
        prefixed = {
            k.removeprefix("segmenter."): v
            for k, v in blob["state_dict"].items()
            if k.startswith("segmenter.")
        }
        if not prefixed:
            raise DataFormatError(path, "checkpoint state_dict has no 'segmenter.*' entries")
        return prefixed, "checkpoint"
    if not all(isinstance(v, Tensor) for v in blob.values()):
        raise DataFormatError(path, "expected a dict of tensors (a state dict)")
    if "conv1.weight" in blob:
        renamed = {f"backbone.{k}": v for k, v in blob.items() if not k.startswith("fc.")}
        return renamed, "torchvision"
    return dict(blob), "segmenter"


def load_segmenter_weights(model: nn.Module, path: str | Path) -> LoadReport:
    """Copy weights from ``path`` into ``model`` (a DeepLabV2 or PSPNet); see the module
    docstring.

    Raises :class:`DataFormatError` naming the file when it is unreadable, when backbone
    tensors are missing, or when their shapes differ from the model's (another architecture).
    """
    path = Path(path)
    state, file_format = _read_state_dict(path)
    own = model.state_dict()

    backbone_keys = [k for k in own if k.startswith("backbone.")]
    missing = [k for k in backbone_keys if k not in state and not k.endswith("num_batches_tracked")]
    if missing:
        raise DataFormatError(
            path,
            f"{len(missing)} backbone tensors missing (e.g. {missing[0]!r}); is this a "
            f"{getattr(model, 'backbone_name', 'matching')} checkpoint?",
        )
    wrong = [k for k in backbone_keys if k in state and state[k].shape != own[k].shape]
    if wrong:
        key = wrong[0]
        raise DataFormatError(
            path,
            f"backbone tensor {key!r} has shape {tuple(state[key].shape)}, the model expects "
            f"{tuple(own[key].shape)} (another backbone architecture?)",
        )
    to_load = {k: state[k] for k in backbone_keys if k in state}

    head_keys = [k for k in own if k.startswith(_HEAD_PREFIXES)]
    note = ""
    heads_loaded = False
    if file_format == "torchvision":
        note = "torchvision ResNet weights: backbone loaded, heads keep their initialisation"
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
    return LoadReport(
        path=str(path),
        file_format=file_format,
        backbone_tensors=sum(1 for k in to_load if k.startswith("backbone.")),
        heads_loaded=heads_loaded,
        note=note,
        ignored_keys=ignored,
    )

"""Reading a ``uss-train`` checkpoint (``.ckpt``) safely, with one clear error per bad file.

A ``uss-train`` checkpoint is a Lightning checkpoint: a dict with ``state_dict`` (the segmenter's
weights under ``segmenter.*``, the discriminators' under ``d_aux.*`` / ``d_main.*``),
``hyper_parameters`` (``class_names``, ``backbone``, loss weights, ...) and, from ``uss-train``,
``iteration``. It is read with ``torch.load(weights_only=True)``: no pickled code is executed.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import DataFormatError

SEGMENTER_PREFIX = "segmenter."
HEAD_WEIGHTS = ("main.branches.0.weight", "main.classifier.weight")
"""Segmenter entries whose first dimension is the class count: DeepLab-v2's main head (its
first ASPP branch), PSPNet's main classifier; the first present counts."""


@dataclass(frozen=True)
class CheckpointInfo:
    """What :func:`read_checkpoint` found in a ``uss-train`` checkpoint."""

    path: Path
    segmenter_state: dict[str, Tensor]
    """The segmenter's weights, ``segmenter.`` prefix removed (loads into a ``DeepLabV2``)."""
    class_names: tuple[str, ...]
    """``hyper_parameters.class_names`` (the project's classes when absent)."""
    num_classes: int
    """Output channels of the segmenter's heads (= ``len(class_names)``, checked)."""
    hyper_parameters: dict[str, Any]
    iteration: int | None
    """Completed training iterations (``None`` when the file does not record them)."""
    state_dict: dict[str, Tensor]
    """The whole ``state_dict`` (segmenter and discriminators)."""


def load_checkpoint_file(path: Path) -> object:
    """``torch.load`` of ``path`` on the CPU with ``weights_only=True`` (no pickled code runs),
    before any check of what it holds.

    Raises:
        DataFormatError: naming ``path``: missing, not a file, empty, truncated or not a torch
            file.
    """
    if not path.exists():
        raise DataFormatError(path, "checkpoint not found")
    if not path.is_file():
        raise DataFormatError(path, "is not a file (expected a uss-train .ckpt)")
    if path.stat().st_size == 0:
        raise DataFormatError(path, "empty file (expected a uss-train .ckpt)")
    try:
        with warnings.catch_warnings():
            # Its pickle-protocol warning would precede our own one-line error.
            warnings.simplefilter("ignore", UserWarning)
            return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # zip, EOF, pickle and decoding errors share no base class
        raise DataFormatError(
            path,
            "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt "
            f"({type(error).__name__}{_detail(error)})",
        ) from error


def _detail(error: Exception) -> str:
    """``": <the informative part>"`` of a torch.load error (its messages run over many lines
    of advice), or ``""``."""
    text = str(error)
    marker = "WeightsUnpickler error: "
    if marker in text:  # weights_only refused: the reason follows the advice
        text = text[text.index(marker) + len(marker) :]
    first = (text.strip().splitlines() or [""])[0].split(". ")[0].strip()
    return f": {first}" if first else ""


def read_checkpoint(path: str | Path, num_classes: int | None = None) -> CheckpointInfo:
    """Open the ``uss-train`` checkpoint ``path`` (CPU tensors) and check what the exporter and
    the trainer rely on.

    Raises :class:`~uss_slam.core.errors.DataFormatError` naming ``path`` when the file is
    missing, empty, truncated or not a torch file; when it is not a Lightning checkpoint (no
    ``state_dict`` / ``hyper_parameters`` dicts) or has no segmenter weights; when
    ``hyper_parameters.class_names`` disagrees with the heads' class count; and when
    ``num_classes`` is given and differs from the checkpoint's class count.
    """
    path = Path(path)
    blob = load_checkpoint_file(path)
    if not isinstance(blob, Mapping):
        raise DataFormatError(
            path, f"not a Lightning checkpoint: holds a {type(blob).__name__}, expected a dict"
        )
    state = blob.get("state_dict")
    if not isinstance(state, Mapping):
        hint = (
            " (a plain state dict?)"
            if blob and all(isinstance(v, Tensor) for v in blob.values())
            else ""
        )
        raise DataFormatError(path, f"not a Lightning checkpoint: no 'state_dict'{hint}")
    hparams = blob.get("hyper_parameters")
    if not isinstance(hparams, Mapping):
        raise DataFormatError(
            path, "not a uss-train checkpoint: no 'hyper_parameters' (class names, backbone)"
        )
    segmenter = {
        k.removeprefix(SEGMENTER_PREFIX): v
        for k, v in state.items()
        if k.startswith(SEGMENTER_PREFIX) and isinstance(v, Tensor)
    }
    if not segmenter:
        raise DataFormatError(path, "checkpoint state_dict has no 'segmenter.*' entries")
    head = next((segmenter[k] for k in HEAD_WEIGHTS if k in segmenter), None)
    if head is None or head.dim() != 4:
        names = " or ".join(f"'{SEGMENTER_PREFIX}{k}'" for k in HEAD_WEIGHTS)
        raise DataFormatError(path, f"no 4-D {names} (not a DeepLab-v2 or PSPNet segmenter?)")
    classes = int(head.shape[0])

    names = hparams.get("class_names")
    if names is None:
        names = CLASS_NAMES
    if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) for n in names):
        raise DataFormatError(
            path, f"hyper_parameters.class_names must be a list of names, got {names!r}"
        )
    if len(names) != classes:
        raise DataFormatError(
            path,
            f"hyper_parameters.class_names lists {len(names)} classes, the segmenter's heads "
            f"output {classes}",
        )
    if num_classes is not None and int(num_classes) != classes:
        raise DataFormatError(
            path,
            f"checkpoint has {classes} classes ({', '.join(names)}), expected {int(num_classes)}",
        )
    iteration = blob.get("iteration")
    if iteration is not None and (isinstance(iteration, bool) or not isinstance(iteration, int)):
        raise DataFormatError(path, f"'iteration' must be an integer, got {iteration!r}")
    return CheckpointInfo(
        path=path,
        segmenter_state=segmenter,
        class_names=tuple(names),
        num_classes=classes,
        hyper_parameters=dict(hparams),
        iteration=iteration,
        state_dict=dict(state),
    )

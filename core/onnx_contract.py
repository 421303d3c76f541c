"""The contract between ``uss-export`` (writer, torch) and the SLAM runtime (reader, no torch).

Pure Python (``json`` only): :mod:`uss_slam.slam_eval` imports it and must never pull in torch.

An exported segmenter (``exports/<name>.onnx``) has

- one input ``image``: uint8 RGB, **NHWC** ``(N, H, W, 3)``, dynamic ``N``, ``H``, ``W``; the
  graph casts to float, divides by 255, normalises with the stored mean/std and transposes to
  NCHW itself;
- two outputs: ``logits`` float32 ``(N, C, H, W)`` at the input size (the chosen head's logits,
  bilinearly upsampled with ``align_corners=True`` as in training and validation) and ``labels``
  uint8 ``(N, H, W)`` = argmax over ``C``;
- the metadata below in the model's ``metadata_props`` (string values; lists and numbers
  JSON-encoded).

Where a model is used (``uss-slam``, ``uss-eval``, ``uss-demo``, ``uss-experiments``), its
outputs are held to the metadata by :func:`check_logit_channels` (one channel per class of
``uss_slam.class_names``) and :func:`check_label_ids` (every label a class id of that list).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

from .errors import DataFormatError

ONNX_FORMAT = "1"
"""Value of ``uss_slam.format``; bumped on any incompatible change of this contract."""

INPUT_NAME = "image"
OUTPUT_LOGITS = "logits"
OUTPUT_LABELS = "labels"
INPUT_LAYOUT = "NHWC"
INPUT_DTYPE = "uint8"
HEADS: tuple[str, ...] = ("main", "aux")

KEY_FORMAT = "uss_slam.format"
KEY_CLASS_NAMES = "uss_slam.class_names"
KEY_DYNAMIC_CLASSES = "uss_slam.dynamic_classes"
KEY_INPUT_LAYOUT = "uss_slam.input_layout"
KEY_INPUT_DTYPE = "uss_slam.input_dtype"
KEY_MEAN = "uss_slam.mean"
KEY_STD = "uss_slam.std"
KEY_HEAD = "uss_slam.head"
KEY_EXPERIMENT = "uss_slam.experiment"
KEY_CHECKPOINT_SHA256 = "uss_slam.checkpoint_sha256"
KEY_VERSION = "uss_slam.version"

ONNX_METADATA_KEYS: tuple[str, ...] = (
    KEY_FORMAT,
    KEY_CLASS_NAMES,
    KEY_DYNAMIC_CLASSES,
    KEY_INPUT_LAYOUT,
    KEY_INPUT_DTYPE,
    KEY_MEAN,
    KEY_STD,
    KEY_HEAD,
    KEY_EXPERIMENT,
    KEY_CHECKPOINT_SHA256,
    KEY_VERSION,
)
"""Every key an exported model must carry in ``metadata_props``."""


@dataclass(frozen=True)
class SegmenterMetadata:
    """The decoded ``metadata_props`` of an exported segmenter.

    ``mean`` / ``std`` are per RGB channel on the 0..1 scale (already applied inside the graph;
    informative for the runtime). ``experiment`` is the training run's name, ``checkpoint_sha256``
    the hex SHA-256 of the exported checkpoint file.
    """

    class_names: tuple[str, ...]
    dynamic_classes: tuple[str, ...]
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    head: str
    experiment: str
    checkpoint_sha256: str
    version: str
    input_layout: str = INPUT_LAYOUT
    input_dtype: str = INPUT_DTYPE
    format: str = ONNX_FORMAT
    extra: Mapping[str, str] = field(default_factory=dict)
    """Other ``metadata_props`` entries (not ours), kept as read."""

    @property
    def dynamic_class_ids(self) -> tuple[int, ...]:
        """Class ids (indices into ``class_names``) of the dynamic classes."""
        return tuple(self.class_names.index(name) for name in self.dynamic_classes)

    def to_props(self) -> dict[str, str]:
        """The ``metadata_props`` entries (key -> string) of this metadata, ours only."""
        return {
            KEY_FORMAT: self.format,
            KEY_CLASS_NAMES: json.dumps(list(self.class_names)),
            KEY_DYNAMIC_CLASSES: json.dumps(list(self.dynamic_classes)),
            KEY_INPUT_LAYOUT: self.input_layout,
            KEY_INPUT_DTYPE: self.input_dtype,
            KEY_MEAN: json.dumps([float(v) for v in self.mean]),
            KEY_STD: json.dumps([float(v) for v in self.std]),
            KEY_HEAD: self.head,
            KEY_EXPERIMENT: self.experiment,
            KEY_CHECKPOINT_SHA256: self.checkpoint_sha256,
            KEY_VERSION: self.version,
        }

    @classmethod
    def from_props(
        cls, props: Mapping[str, str], path: str | PathLike[str] = "<model>"
    ) -> SegmenterMetadata:
        """Decode and check ``metadata_props`` (e.g. onnxruntime's
        ``session.get_modelmeta().custom_metadata_map``); ``path`` names the model in errors.

        Raises :class:`DataFormatError` when a key is missing, malformed, or the format,
        layout or dtype is not the one this code reads.
        """
        missing = [key for key in ONNX_METADATA_KEYS if key not in props]
        if missing:
            raise DataFormatError(
                path,
                f"not a uss-slam segmenter: metadata_props lacks {', '.join(missing)} "
                "(export it with uss-export)",
            )
        if props[KEY_FORMAT] != ONNX_FORMAT:
            raise DataFormatError(
                path, f"{KEY_FORMAT} is {props[KEY_FORMAT]!r}, this code reads {ONNX_FORMAT!r}"
            )
        for key, expected in ((KEY_INPUT_LAYOUT, INPUT_LAYOUT), (KEY_INPUT_DTYPE, INPUT_DTYPE)):
            if props[key] != expected:
                raise DataFormatError(path, f"{key} is {props[key]!r}, expected {expected!r}")
        class_names = _string_list(props, KEY_CLASS_NAMES, path)
        if not class_names or len(set(class_names)) != len(class_names):
            raise DataFormatError(path, f"{KEY_CLASS_NAMES} must be non-empty and unique")
        dynamic = _string_list(props, KEY_DYNAMIC_CLASSES, path)
        unknown = [name for name in dynamic if name not in class_names]
        if unknown:
            raise DataFormatError(
                path, f"{KEY_DYNAMIC_CLASSES} {unknown} are not in {KEY_CLASS_NAMES} {class_names}"
            )
        if props[KEY_HEAD] not in HEADS:
            raise DataFormatError(
                path, f"{KEY_HEAD} is {props[KEY_HEAD]!r}, expected one of {HEADS}"
            )
        ours = set(ONNX_METADATA_KEYS)
        return cls(
            class_names=tuple(class_names),
            dynamic_classes=tuple(dynamic),
            mean=_rgb(props, KEY_MEAN, path),
            std=_rgb(props, KEY_STD, path),
            head=props[KEY_HEAD],
            experiment=props[KEY_EXPERIMENT],
            checkpoint_sha256=props[KEY_CHECKPOINT_SHA256],
            version=props[KEY_VERSION],
            input_layout=props[KEY_INPUT_LAYOUT],
            input_dtype=props[KEY_INPUT_DTYPE],
            format=props[KEY_FORMAT],
            extra={k: v for k, v in props.items() if k not in ours},
        )


def _json(props: Mapping[str, str], key: str, path: str | PathLike[str]) -> object:
    try:
        return json.loads(props[key])
    except json.JSONDecodeError as error:
        raise DataFormatError(path, f"{key} is not JSON ({error}): {props[key]!r}") from None


def _string_list(props: Mapping[str, str], key: str, path: str | PathLike[str]) -> list[str]:
    value = _json(props, key, path)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise DataFormatError(path, f"{key} must be a JSON list of strings, got {props[key]!r}")
    return value


def _rgb(
    props: Mapping[str, str], key: str, path: str | PathLike[str]
) -> tuple[float, float, float]:
    value = _json(props, key, path)
    ok = (
        isinstance(value, list)
        and len(value) == 3
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    )
    if not ok:
        raise DataFormatError(path, f"{key} must be a JSON list of 3 numbers, got {props[key]!r}")
    r, g, b = (float(v) for v in value)  # type: ignore[union-attr]
    return r, g, b


def check_logit_channels(
    path: str | PathLike[str], class_names: Sequence[str], channels: int | None
) -> None:
    """Refuse a model whose ``logits`` have another number of channels than ``class_names``
    (the metadata's class list) has entries; ``channels`` None (not known yet) passes.

    Raises :class:`DataFormatError` naming the model file.
    """
    if channels is None or int(channels) == len(class_names):
        return
    raise DataFormatError(
        path,
        f"output {OUTPUT_LOGITS!r} has {int(channels)} channels but {KEY_CLASS_NAMES} lists "
        f"{len(class_names)} classes ({', '.join(class_names)}); the model and its metadata "
        "disagree (re-export it with uss-export)",
    )


def check_label_ids(path: str | PathLike[str], class_names: Sequence[str], labels: Any) -> None:
    """Refuse a model whose ``labels`` (an array of the model's class indices, any shape) hold
    an id that is not a class of ``class_names`` (ids ``0 .. len - 1``): one pass for the
    largest id, cheap enough for every frame.

    Raises :class:`DataFormatError` naming the model file.
    """
    if not getattr(labels, "size", 0):
        return
    top = int(labels.max())
    if top < len(class_names):
        return
    raise DataFormatError(
        path,
        f"output {OUTPUT_LABELS!r} holds class id {top}, but {KEY_CLASS_NAMES} lists "
        f"{len(class_names)} classes (ids 0..{len(class_names) - 1}: "
        f"{', '.join(class_names)}); the model and its metadata disagree",
    )

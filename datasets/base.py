"""The shared sample type and base class of every image (+ label) dataset.

A dataset is a list of :class:`ImageItem` (image path, optional label path, name) plus a
look-up table that maps the file's label values to project classes (``classes.voc_lut()`` for
VOC and SBD, identity for the project's own label PNGs). Subclasses build the item list and,
when their labels are not PNGs of class indices, override :meth:`SegmentationDataset.read_label`
(SBD: ``.mat`` structs, COCO: rasterised annotations).

Bad input follows one policy, ``on_error``: ``"raise"`` stops with a
:class:`~uss_slam.core.errors.DataFormatError` naming the file (and line), ``"skip"`` leaves
the item out and records the error in ``dataset.skipped`` (reported in the selection summary).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypedDict

import numpy as np
import torch
from PIL import Image as PILImage
from torch.utils.data import Dataset
from torchvision import tv_tensors

from uss_slam.core.classes import IGNORE_INDEX, NUM_CLASSES
from uss_slam.core.errors import DataFormatError
from uss_slam.core.images import (
    check_label_values,
    format_problem,
    read_rgb,
    sixteen_bit_problem,
)
from uss_slam.core.images import read_label_values as core_label_values
from uss_slam.datasets.transforms import eval_transform

log = logging.getLogger(__name__)

OnError = Literal["raise", "skip"]
ON_ERROR_CHOICES: tuple[str, ...] = ("raise", "skip")


class SegmentationSample(TypedDict, total=False):
    """One sample after transforms; the data module collates these into batches of ``N``."""

    image: torch.Tensor  # (3, H, W) float32, normalised
    label: torch.Tensor  # (H, W) int64 project class ids, IGNORE_INDEX = ignore
    name: str


@dataclass(frozen=True)
class ImageItem:
    image: Path
    label: Path | None
    name: str


@dataclass(frozen=True)
class LabelStats:
    """What selection needs to know of one label: pixels per project class and its size.

    ``counts`` has ``NUM_CLASSES`` entries (ignore pixels are not counted); sizes in pixels.
    """

    counts: np.ndarray
    height: int
    width: int


Transform = Callable[[dict[str, Any]], dict[str, Any]]


def check_on_error(on_error: str) -> OnError:
    """Validate an ``on_error`` setting (``raise`` or ``skip``)."""
    if on_error not in ON_ERROR_CHOICES:
        raise ValueError(f"on_error must be one of {ON_ERROR_CHOICES}, got {on_error!r}")
    return on_error  # type: ignore[return-value]


def handle_bad_input(error: DataFormatError, on_error: OnError, skipped: list) -> None:
    """Raise ``error`` (``on_error="raise"``) or record it in ``skipped``."""
    if on_error == "raise":
        raise error
    skipped.append(error)


def report_skipped(what: str, skipped: Sequence[DataFormatError], shown: int = 5) -> None:
    """Log a warning that lists (the first few of) the inputs skipped by ``on_error: skip``."""
    if not skipped:
        return
    lines = "\n  ".join(str(error) for error in skipped[:shown])
    more = f"\n  ... and {len(skipped) - shown} more" if len(skipped) > shown else ""
    log.warning(
        "%s: skipped %d bad input(s) (on_error=skip):\n  %s%s", what, len(skipped), lines, more
    )


def identity_lut() -> np.ndarray:
    """Label values 0..NUM_CLASSES-1 and 255 kept; a value outside them is an error (``-1``)."""
    lut = np.full(256, -1, dtype=np.int16)
    lut[:NUM_CLASSES] = np.arange(NUM_CLASSES)
    lut[IGNORE_INDEX] = IGNORE_INDEX
    return lut


# The bytes a complete file ends with. Decoders fill a truncated image with grey or fail late;
# checking the end marker finds truncation from a few bytes, without decoding. Files with data
# after the end marker (some cameras and editors append it) are told apart by a slower check.
_JPEG_START, _JPEG_END = b"\xff\xd8", b"\xff\xd9"
_PNG_START, _PNG_END = b"\x89PNG\r\n\x1a\n", b"IEND"
_PNG_IEND_CHUNK = b"IEND\xaeB`\x82"  # chunk type + its CRC: unambiguous anywhere in the file


def _truncation(path: Path, head: bytes, tail: bytes) -> str | None:
    """Why a JPEG / PNG whose first and last bytes are ``head`` / ``tail`` is incomplete."""
    if head.startswith(_JPEG_START) and _JPEG_END not in tail:
        try:  # trailing bytes after a complete image, or a truncated one? Decode to know.
            with PILImage.open(path) as image:
                image.load()
        except (OSError, SyntaxError, ValueError):  # what PIL raises for damaged files
            return "truncated JPEG: no end-of-image marker (FFD9) at the end of the file"
    png = head.startswith(_PNG_START) and _PNG_END not in tail
    if png and _PNG_IEND_CHUNK not in Path(path).read_bytes():
        return "truncated PNG: no IEND chunk at the end of the file"
    return None


def inspect_image(path: Path) -> tuple[int, int]:
    """``(width, height)`` of a colour image file from its header, after checking it is
    complete, its content the format its name says and 8 bits per channel (the checks of
    :func:`read_image`, which reads it later).

    Cheap (reads the header and the last bytes, decodes no pixels); raises
    :class:`DataFormatError` for a missing, unreadable, truncated or mislabelled file.
    """
    try:
        with open(path, "rb") as file:
            head = file.read(32)
            file.seek(0, 2)
            file.seek(max(0, file.tell() - 64))
            tail = file.read()
        reason = format_problem(path, head) or sixteen_bit_problem(head)
        reason = reason or _truncation(path, head, tail)
        if reason:
            raise DataFormatError(path, reason)
        with PILImage.open(path) as image:
            return image.size
    except DataFormatError:
        raise
    except FileNotFoundError:
        raise DataFormatError(path, "image file not found") from None
    except (OSError, ValueError) as error:  # PIL.UnidentifiedImageError is an OSError
        raise DataFormatError(path, f"cannot read image ({error})") from error


def read_image(path: Path) -> tv_tensors.Image:
    """An image file (JPEG / PNG, any channel count) -> ``(3, H, W)`` uint8 RGB, read by the
    project's one colour reader (:func:`uss_slam.core.images.read_rgb`: the file whole, its
    content the format its name says, 8 bits per channel, the stored pixels)."""
    return tv_tensors.Image(torch.from_numpy(read_rgb(path)).permute(2, 0, 1))


def read_label_values(path: Path) -> np.ndarray:
    """The raw ``(H, W)`` uint8 values of a single-channel label PNG (a palette's indices, or
    grey), read by the project's one label reader
    (:func:`uss_slam.core.images.read_label_values`: the file whole, a damaged or truncated
    one named, as every tool reads labels)."""
    return core_label_values(path)


def map_label(path: Path, values: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """File values -> project ids through ``lut`` (``-1`` entries: values that must not occur).
    The project's own labels (the identity) are checked as every tool checks them."""
    if np.array_equal(lut, identity_lut()):
        check_label_values(path, values, NUM_CLASSES)
    mapped = lut[values]
    if mapped.size and mapped.min() < 0:
        bad = sorted(set(np.unique(values[mapped < 0]).tolist()))[:5]
        raise DataFormatError(path, f"label values {bad} are not valid class indices")
    return mapped.astype(np.uint8)


def read_label(path: Path, lut: np.ndarray) -> tv_tensors.Mask:
    """A single-channel label PNG (palette 'P' or grey 'L') -> ``(H, W)`` uint8 project ids.

    ``lut`` (256 entries) maps file values to project classes; ``-1`` entries mark values that
    must not occur.
    """
    return tv_tensors.Mask(torch.from_numpy(map_label(path, read_label_values(path), lut)))


def label_stats(label: np.ndarray) -> LabelStats:
    """Pixels per project class of a ``(H, W)`` label of project ids (255 not counted)."""
    counts = np.bincount(label.ravel(), minlength=256)[:NUM_CLASSES].astype(np.int64)
    return LabelStats(counts=counts, height=int(label.shape[0]), width=int(label.shape[1]))


def finish_sample(sample: dict[str, Any]) -> SegmentationSample:
    """Transformed sample dict -> plain tensors (``label`` as int64)."""
    out: SegmentationSample = {"image": sample["image"].as_subclass(torch.Tensor)}
    if "label" in sample:
        out["label"] = sample["label"].as_subclass(torch.Tensor).to(torch.int64)
    out["name"] = sample["name"]
    return out


class SegmentationDataset(Dataset):
    """Images with optional labels; ``__getitem__`` returns a :class:`SegmentationSample`.

    ``cache_label_stats``: selection may cache :meth:`label_stats` by label file (false when
    several items share one label file, as COCO's annotation JSON).

    Args:
        items: the files, one :class:`ImageItem` each (label ``None`` = unlabelled).
        lut: 256-entry table from label-file values to project classes (``-1`` = invalid).
        transform: joint v2 transform of the sample dict; default: normalisation only.
        skipped: bad inputs the subclass left out while listing (``on_error="skip"``).
    """

    cache_label_stats = True

    def __init__(
        self,
        items: Sequence[ImageItem],
        lut: np.ndarray | None = None,
        transform: Transform | None = None,
        skipped: Sequence[DataFormatError] = (),
    ) -> None:
        self.items = list(items)
        self.lut = identity_lut() if lut is None else lut
        self.transform = transform if transform is not None else eval_transform()
        self.skipped: list[DataFormatError] = list(skipped)

    def __len__(self) -> int:
        return len(self.items)

    @property
    def labelled(self) -> bool:
        return bool(self.items) and all(item.label is not None for item in self.items)

    def read_label(self, index: int) -> np.ndarray:
        """``(H, W)`` uint8 project class ids of item ``index`` (its label must exist)."""
        item = self.items[index]
        assert item.label is not None
        return map_label(item.label, read_label_values(item.label), self.lut)

    def label_stats(self, index: int) -> LabelStats:
        """Pixels per class and size of item ``index``'s label (selection reads every label)."""
        return label_stats(self.read_label(index))

    def check_image(self, index: int, height: int, width: int) -> None:
        """Check item ``index``'s image file is complete and ``width × height`` (header only)."""
        item = self.items[index]
        image_width, image_height = inspect_image(item.image)
        if (image_width, image_height) != (width, height):
            raise DataFormatError(
                item.label if item.label is not None else item.image,
                f"label is {width}×{height} but its image {item.image.name} is "
                f"{image_width}×{image_height}",
            )

    def load(self, index: int) -> dict[str, Any]:
        """The untransformed sample: uint8 image and mask tv_tensors, and the name."""
        item = self.items[index]
        sample: dict[str, Any] = {"image": read_image(item.image), "name": item.name}
        if item.label is not None:
            label = tv_tensors.Mask(torch.from_numpy(self.read_label(index)))
            if label.shape[-2:] != sample["image"].shape[-2:]:
                raise DataFormatError(
                    item.label,
                    f"label is {label.shape[-1]}×{label.shape[-2]} but its image "
                    f"{item.image.name} is {sample['image'].shape[-1]}×"
                    f"{sample['image'].shape[-2]}",
                )
            sample["label"] = label
        return sample

    def __getitem__(self, index: int) -> SegmentationSample:
        return finish_sample(self.transform(self.load(index)))

"""A bounded look at the training data's files before the trainer starts.

A label holding a value that is no class id, or a truncated image, is otherwise found when a
batch reads it: after Lightning's device lines, or never (an item no batch draws). Before the
trainer is built, :func:`check_data_files` reads the label of every labelled item (the value
check of the dataset's own reader) and checks the structure of every image (PNG chunks and
CRCs, JPEG markers up to the end-of-image marker: no decode), validation set first, then the
source and target sets, within a budget of files and seconds; what the budget leaves is
checked as before, when it is read. A label PNG of VOC's size decodes in about 1 ms, so the
default budget (4000 files, 30 s) covers the CI and demo sets and VOC's 1464 training images;
``SelectedSources`` read every label already while selecting, and only their images are
checked here.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

from torch.utils.data import ConcatDataset, Subset

from uss_slam.core.errors import DataFormatError
from uss_slam.core.images import image_problem
from uss_slam.datasets.base import SegmentationDataset

MAX_FILES = 4000
"""Items checked up front at most (over every dataset of the data module)."""
MAX_SECONDS = 30.0
"""Seconds of checking at most; the rest is checked when a batch reads it."""


def _items(dataset: Any, labels: bool = True) -> Iterator[tuple[SegmentationDataset, int, bool]]:
    """(dataset, item index, whether to read its label) of every item ``dataset`` draws from."""
    if isinstance(dataset, SegmentationDataset):
        for index in range(len(dataset.items)):
            yield dataset, index, labels
    elif isinstance(dataset, Subset):
        inner = dataset.dataset
        if isinstance(inner, SegmentationDataset):
            for index in dataset.indices:
                yield inner, int(index), labels
        else:
            yield from _items(inner, labels)
    elif isinstance(dataset, ConcatDataset):
        for part in dataset.datasets:
            yield from _items(part, labels)
    elif hasattr(dataset, "index") and hasattr(dataset, "sets"):  # SelectedSources
        for name, index in dataset.index:  # its selection read every label already
            yield dataset.sets[name], index, False
    elif hasattr(dataset, "dataset"):  # a wrapper (a transform, a seeded stream)
        yield from _items(dataset.dataset, labels)


def check_item(dataset: SegmentationDataset, index: int, label: bool) -> None:
    """Check item ``index``: its image's structure and, with ``label``, its label's values and
    size against the image's header. Raises :class:`DataFormatError` naming the file."""
    item = dataset.items[index]
    try:
        data = item.image.read_bytes()
    except OSError as error:
        raise DataFormatError(item.image, f"cannot read the image ({error.strerror})") from None
    reason = image_problem(data)
    if reason:
        raise DataFormatError(item.image, reason)
    if label and item.label is not None:
        values = dataset.read_label(index)
        dataset.check_image(index, int(values.shape[0]), int(values.shape[1]))


def check_data_files(
    datamodule: Any, max_files: int = MAX_FILES, max_seconds: float = MAX_SECONDS
) -> int:
    """Check the files of ``datamodule``'s ``val``, ``source`` and ``target`` sets (in that
    order) within ``max_files`` items and ``max_seconds`` s; returns the items checked.

    Raises:
        DataFormatError: the first bad file (its path, and the reader's reason).
    """
    start = time.perf_counter()
    checked = 0
    seen: set[tuple[int, int]] = set()
    for name in ("val", "source", "target"):
        for dataset, index, label in _items(getattr(datamodule, name, None)):
            if (id(dataset), index) in seen:
                continue
            if checked >= max_files or time.perf_counter() - start > max_seconds:
                return checked
            seen.add((id(dataset), index))
            check_item(dataset, index, label)
            checked += 1
    return checked

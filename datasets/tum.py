"""Frames of TUM RGB-D sequences as a segmentation dataset (the target domain).

Reads ``rgb.txt`` with :func:`uss_slam.datasets.tum_io.read_file_list`. Optional labels come
from ``labels/<same file name as the rgb image>`` (uint8 project class ids, as the synthetic
sequences write them): needed for validation, unused for unlabelled target training.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from uss_slam.datasets.errors import DataFormatError
from uss_slam.datasets.segmentation import ImageItem, SegmentationDataset, Transform
from uss_slam.datasets.tum_io import read_file_list


def _sequence_items(root: Path, labels: bool, stride: int) -> list[ImageItem]:
    list_file = root / "rgb.txt"
    if not list_file.is_file():
        raise DataFormatError(list_file, "not a TUM RGB-D sequence: rgb.txt not found")
    frames = read_file_list(list_file)
    if len(frames) == 0:
        raise DataFormatError(list_file, "the sequence lists no images")
    if labels and not (root / "labels").is_dir():
        raise DataFormatError(root / "labels", "labels requested but the folder does not exist")
    items = []
    for index in range(0, len(frames), stride):
        image = frames.resolve(index)
        if not image.is_file():
            raise DataFormatError(list_file, f"listed image {frames.files[index]} not found")
        label = root / "labels" / Path(frames.files[index]).name if labels else None
        if label is not None and not label.is_file():
            raise DataFormatError(
                label, f"label of {frames.files[index]} not found (labels/ must mirror rgb/)"
            )
        items.append(ImageItem(image, label, f"{root.name}/{frames.stamps[index]:.6f}"))
    return items


class TUMFrames(SegmentationDataset):
    """Every ``stride``-th frame of one or more TUM sequences.

    Args:
        roots: sequence folder(s) holding ``rgb.txt``.
        labels: also load ``labels/`` (error if missing); ``False`` gives unlabelled samples.
        transform: joint v2 transform (see :mod:`uss_slam.datasets.transforms`).
        stride: keep one frame in ``stride`` (consecutive frames are nearly identical).

    Samples: ``image (3, H, W)`` float32, ``label (H, W)`` int64 when ``labels``, and
    ``name = "<sequence folder>/<timestamp>"``.
    """

    def __init__(
        self,
        roots: str | Path | Sequence[str | Path],
        labels: bool = False,
        transform: Transform | None = None,
        stride: int = 1,
    ) -> None:
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        paths = [Path(roots)] if isinstance(roots, (str, Path)) else [Path(r) for r in roots]
        if not paths:
            raise ValueError("TUMFrames needs at least one sequence folder")
        self.roots = paths
        items = [item for root in paths for item in _sequence_items(root, labels, stride)]
        super().__init__(items, lut=None, transform=transform)

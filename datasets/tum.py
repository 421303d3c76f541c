"""Frames of TUM RGB-D sequences as a segmentation dataset (the target domain).

Reads the folder with :func:`uss_slam.core.tum_io.read_tum_folder` (``rgb.txt``; depth is not
needed), the same reader the SLAM harness uses.
Optional labels come from ``labels/<same file name as the rgb image>`` (uint8 project class
ids, as the synthetic sequences write them): needed for validation, unused for unlabelled
target training.

Held-out frames: ``holdout`` keeps the last fraction of every sequence (in time) out of the
``train`` part; ``part="holdout"`` returns exactly those frames (for evaluation, e.g. after
labelling them). ``exclude`` leaves out frames listed in files: a COCO JSON (its images'
``file_name``) or a text list of rgb file names, matched by file name — the frames you
labelled yourself for validation, so that they never train the adaptation.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Literal

from uss_slam.core.errors import DataFormatError
from uss_slam.core.ranges import Range
from uss_slam.core.tum_io import read_tum_folder
from uss_slam.datasets.base import (
    ImageItem,
    OnError,
    SegmentationDataset,
    Transform,
    check_on_error,
    handle_bad_input,
    inspect_image,
    report_skipped,
)

Part = Literal["train", "holdout"]


def read_frame_names(path: Path) -> set[str]:
    """File names (no folders) of the frames a COCO JSON or a text list names.

    Text lists: one entry per line, either ``file`` or ``timestamp file`` (as ``rgb.txt``);
    ``#`` starts a comment.
    """
    if not path.is_file():
        raise DataFormatError(path, "frame list not found")
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            return {Path(str(image["file_name"])).name for image in data["images"]}
        except json.JSONDecodeError as error:
            raise DataFormatError(path, f"not valid JSON: {error.msg}", error.lineno) from None
        except (KeyError, TypeError):
            raise DataFormatError(path, "expected a COCO JSON with images[].file_name") from None
    names: set[str] = set()
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) > 2:
            raise DataFormatError(
                path, f"expected 'file' or 'timestamp file', got {len(fields)} fields", number
            )
        names.add(Path(fields[-1]).name)
    return names


def _sequence_items(
    root: Path,
    labels: bool,
    stride: int,
    holdout: float,
    part: Part,
    gap: int,
    excluded: set[str],
    on_error: OnError,
    skipped: list[DataFormatError],
) -> list[ImageItem]:
    folder = read_tum_folder(
        root, depth=False, labels=labels, skipped=skipped if on_error == "skip" else None
    )
    frames = folder.frames
    held = math.ceil(holdout * len(frames)) if holdout > 0 else 0
    first_held = len(frames) - held
    span = range(0, max(0, first_held - gap)) if part == "train" else range(first_held, len(frames))
    items = []
    for index in span[::stride]:
        frame = frames[index]
        if frame.rgb.name in excluded:
            continue
        error = folder.missing(frame)
        if error is None:
            try:  # header and end marker only: a truncated frame fails here, not mid-training
                inspect_image(frame.rgb)
            except DataFormatError as bad:
                error = bad
        if error is not None:
            handle_bad_input(error, on_error, skipped)
            continue
        items.append(ImageItem(frame.rgb, frame.labels, f"{folder.root.name}/{frame.stamp:.6f}"))
    return items


class TUMFrames(SegmentationDataset):
    """Every ``stride``-th frame of one or more TUM sequences.

    Args:
        roots: sequence folder(s) holding ``rgb.txt`` and ``rgb/``.
        labels: also load ``labels/`` (error if missing); ``False`` gives unlabelled samples.
        transform: joint v2 transform (see :mod:`uss_slam.datasets.transforms`).
        stride: keep one frame in ``stride`` (consecutive frames are nearly identical).
        holdout: fraction of each sequence (its last frames, in time) held out of ``train``.
        part: ``train`` (the frames before the held-out block; all frames when ``holdout`` is 0)
            or ``holdout`` (the held-out block).
        holdout_gap: frames between the two parts that neither uses (neighbouring frames are
            near-duplicates).
        exclude: files listing frames to leave out (COCO JSON or text list, matched by file
            name).
        on_error: ``raise``: an unparsable ``rgb.txt`` line, a listed image (label) that does
            not exist, or a truncated / unreadable image is an error naming the file (and line);
            ``skip``: left out, counted in ``skipped`` and logged.

    Samples: ``image (3, H, W)`` float32, ``label (H, W)`` int64 when ``labels``, and
    ``name = "<sequence folder>/<timestamp>"``.
    """

    def __init__(
        self,
        roots: Annotated[str | Path | Sequence[str | Path], Range(unique=True)],
        labels: bool = False,
        transform: Transform | None = None,
        stride: Annotated[int, Range(min=1)] = 1,
        holdout: Annotated[float, Range(min=0, lt=1)] = 0.0,
        part: Part = "train",
        holdout_gap: Annotated[int, Range(min=0)] = 0,
        exclude: Sequence[str | Path] = (),
        on_error: OnError = "raise",
    ) -> None:  # the ranges: the config's schema (data.<split>.*)
        if part == "holdout" and holdout == 0:
            raise ValueError("part='holdout' needs holdout > 0")
        self.on_error = check_on_error(on_error)
        paths = [Path(roots)] if isinstance(roots, (str, Path)) else [Path(r) for r in roots]
        if not paths:
            raise ValueError("TUMFrames needs at least one sequence folder")
        self.roots = paths
        excluded: set[str] = set()
        for path in exclude or ():
            excluded |= read_frame_names(Path(path))
        skipped: list[DataFormatError] = []
        items = [
            item
            for root in paths
            for item in _sequence_items(
                root, labels, stride, holdout, part, holdout_gap, excluded, self.on_error, skipped
            )
        ]
        report_skipped(f"TUM frames ({', '.join(str(p) for p in paths)})", skipped)
        if not items:
            raise DataFormatError(
                paths[0],
                f"no frames left in {len(paths)} sequence(s) (part={part}, "
                f"holdout={holdout}, {len(excluded)} excluded names, {len(skipped)} skipped)",
            )
        super().__init__(items, lut=None, transform=transform, skipped=skipped)

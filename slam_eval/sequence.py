"""TUM RGB-D sequences for the SLAM run: frame selection, image decoding and checks, prefetching.

The folder layout (``rgb.txt``, ``depth.txt``, optional ``groundtruth.txt``, ``intrinsics.yaml``
and ``labels/``), the rgb/depth association and the camera come from
:mod:`uss_slam.core.tum_io` (:func:`~uss_slam.core.tum_io.read_tum_folder`,
:func:`~uss_slam.core.tum_io.resolve_camera`). A colour frame without a depth partner is not
silently dropped: it is counted in :attr:`TumSequence.unmatched_rgb`.
"""

from __future__ import annotations

import itertools
import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import cv2
import numpy as np

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.images import check_colour, read_depth, read_grey, read_rgb
from uss_slam.core.images import read_labels as read_label_image
from uss_slam.core.tum_io import (
    StrPath,
    Trajectory,
    read_trajectory,
    read_tum_folder,
    resolve_camera,
)

T = TypeVar("T")
S = TypeVar("S")

MIN_STRIDED_FRAMES = 10
"""Fewest frames a ``stride`` > 1 may leave of a sequence (before ``max_frames``): fewer give no
trajectory worth scoring, and a table of strides would compare a handful of poses."""


@dataclass(frozen=True)
class FrameRecord:
    """One associated rgb/depth pair of a sequence (paths absolute, stamps in seconds)."""

    index: int
    stamp: float
    rgb_path: Path
    depth_stamp: float
    depth_path: Path
    labels_path: Path | None


@dataclass
class Frame:
    """A loaded frame.

    ``rgb`` (H, W, 3) uint8 in RGB order; ``gray`` (H, W) uint8; ``depth`` (H, W) float32 metres,
    0 where the sensor has no measurement; ``labels`` (H, W) uint8 class ids or None.
    """

    index: int
    stamp: float
    rgb: np.ndarray
    gray: np.ndarray
    depth: np.ndarray
    labels: np.ndarray | None = None
    read_time: tuple[float, float] = (0.0, 0.0)
    """Wall and CPU seconds spent reading and decoding this frame."""


class TumSequence:
    """A TUM RGB-D sequence on disk.

    Args:
        path: the sequence folder.
        camera: ``None``/``"auto"``, ``"fr1" | "fr2" | "fr3"`` or a path (see :func:`~uss_slam.core.tum_io.resolve_camera`).
        max_diff: largest rgb/depth stamp difference accepted by the association, seconds.
        load_labels: also load ``labels/<rgb file name>`` with every frame (oracle segmentation).
        start, stride, max_frames: which associated frames to use (``max_frames`` None = all).
        min_strided_frames: a ``stride`` > 1 that leaves fewer frames than this is one line
            naming ``sequence.stride`` (the SLAM runs pass :data:`MIN_STRIDED_FRAMES`; 0 = no
            floor, e.g. for scoring masks on every n-th frame).

    Every listed image is checked to exist when the sequence is opened, so a run never fails
    half-way on a missing file; sizes and dtypes are checked on the first frame and on every load.
    """

    def __init__(
        self,
        path: StrPath,
        *,
        camera: str | None = None,
        max_diff: float = 0.02,
        load_labels: bool = False,
        start: int = 0,
        stride: int = 1,
        max_frames: int | None = None,
        min_strided_frames: int = 0,
    ) -> None:
        self.path = Path(os.path.expanduser(path))
        if stride < 1 or start < 0 or (max_frames is not None and max_frames < 1):
            raise UssSlamError(
                f"sequence: start must be >= 0, stride >= 1 and max_frames >= 1 or null "
                f"(got start={start}, stride={stride}, max_frames={max_frames})"
            )
        folder = read_tum_folder(self.path, depth=True, labels=load_labels, max_diff=max_diff)
        self.max_diff = max_diff
        self.unmatched_rgb = folder.unmatched_rgb
        """Colour frames without a depth frame within ``max_diff`` (not processed, reported)."""
        self.load_labels = load_labels
        selected = folder.frames[start::stride]
        if min_strided_frames:  # a SLAM run: too few frames to initialise and track
            _check_stride(
                stride, len(selected), len(folder.frames[start:]), self.path, min_strided_frames
            )
        if max_frames is not None:
            selected = selected[:max_frames]
        if not selected:
            raise UssSlamError(
                f"sequence.start={start}: past the {len(folder.frames)} associated frames of "
                f"{self.path}; expected 0..{max(len(folder.frames) - 1, 0)}"
            )
        for files in selected:
            error = folder.missing(files)
            if error is not None:
                raise error
        self.records: list[FrameRecord] = [
            FrameRecord(k, f.stamp, f.rgb, f.depth_stamp, f.depth, f.labels)
            for k, f in enumerate(selected)
        ]
        first = read_grey(self.records[0].rgb_path)
        self.image_size: tuple[int, int] = (first.shape[1], first.shape[0])
        """``(width, height)`` of every frame, pixels."""
        self.camera, self.camera_source = resolve_camera(
            camera, self.path, self.image_size, key="sequence.camera"
        )
        self.load(0)  # format checks of the first frame before any work starts
        gt_path = folder.groundtruth
        self.groundtruth: Trajectory | None = None if gt_path is None else read_trajectory(gt_path)

    def __len__(self) -> int:
        return len(self.records)

    @property
    def stamps(self) -> np.ndarray:
        """``(N,)`` colour stamps of the selected frames, seconds."""
        return np.array([r.stamp for r in self.records])

    def check_colour_frames(self) -> None:
        """Refuse the first colour frame that is not whole, not what its name says or 16-bit,
        from the files' bytes (no decoding): for a caller about to spend minutes before its
        SLAM run reads them (``uss-demo``)."""
        for record in self.records:
            check_colour(record.rgb_path)

    def load(self, index: int) -> Frame:
        """Read frame ``index`` from disk, checking formats and sizes (errors name the file)."""
        wall, cpu = time.perf_counter(), time.thread_time()
        rgb, gray = self.load_colour(index)
        depth, labels = self.load_depth_and_labels(index)
        spent = (time.perf_counter() - wall, time.thread_time() - cpu)
        return Frame(index, self.records[index].stamp, rgb, gray, depth, labels, spent)

    def load_colour(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``index``'s ``(H, W, 3)`` uint8 RGB and ``(H, W)`` uint8 grey images:
        :meth:`load` without :meth:`load_depth_and_labels`, which the frame reader process
        leaves to the main process unless it is behind."""
        record = self.records[index]
        rgb = read_rgb(record.rgb_path)
        if (rgb.shape[1], rgb.shape[0]) != self.image_size:  # the odd one out is named
            raise DataFormatError(
                record.rgb_path,
                f"image is {rgb.shape[1]}x{rgb.shape[0]} but the sequence's first frame is "
                f"{self.image_size[0]}x{self.image_size[1]}",
            )
        # The same grey as from the BGR image (integer weights: the order cannot round
        # differently).
        return rgb, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)

    def load_depth_and_labels(self, index: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Frame ``index``'s depth (:meth:`load_depth`) and labels (:meth:`load_frame_labels`;
        None without a labels folder)."""
        labelled = self.records[index].labels_path is not None
        return self.load_depth(index), self.load_frame_labels(index) if labelled else None

    def load_depth(self, index: int) -> np.ndarray:
        """Frame ``index``'s ``(H, W)`` float32 depth, metres (0 = no measurement), checked to be
        a single-channel uint16 PNG of the sequence's image size."""
        record = self.records[index]
        raw = read_depth(record.depth_path)
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise DataFormatError(
                record.depth_path,
                f"expected a single-channel uint16 depth PNG, got {raw.dtype} with shape {raw.shape}",
            )
        width, height = self.image_size
        if raw.shape != (height, width):
            raise DataFormatError(
                record.depth_path,
                f"depth image is {raw.shape[1]}x{raw.shape[0]} but the colour image "
                f"{record.rgb_path.name} is {width}x{height}",
            )
        depth = np.empty(raw.shape, np.float32)
        np.multiply(raw, np.float32(1.0 / self.camera.depth_scale), out=depth)
        return depth

    def load_frame_labels(self, index: int) -> np.ndarray:
        """Frame ``index``'s ``(H, W)`` uint8 labels (the sequence has a labels folder)."""
        record = self.records[index]
        assert record.labels_path is not None
        width, height = self.image_size
        return read_labels(record.labels_path, (height, width), record.rgb_path.name)

    def frames(self, prefetch: int = 4, workers: int = 1) -> Iterator[Frame]:
        """Yield every selected frame in order, loading up to ``prefetch`` frames ahead.

        Loading runs in one background thread (PNG decoding releases the GIL), so it overlaps the
        caller's work; a loading error is raised here, at the frame that failed.
        """
        return self.prepared(_identity, prefetch, workers)

    def prepared(
        self, prepare: Callable[[Frame], T], prefetch: int = 4, workers: int = 1
    ) -> Iterator[T]:
        """Yield ``prepare(frame)`` for every selected frame in order.

        With ``prefetch > 0`` loading *and* ``prepare`` run in ``workers`` background threads, up
        to ``prefetch`` frames ahead (the SLAM pipeline extracts ORB features there while the
        caller tracks the previous frame); ``prefetch = 0`` does everything in the caller's thread.
        Results come in frame order whatever the number of workers.
        """
        if prefetch <= 0:
            for k in range(len(self)):
                yield prepare(self.load(k))
            return

        def job(k: int) -> T:
            return prepare(self.load(k))

        yield from ahead(job, iter(range(len(self))), prefetch, workers)


def ahead(
    job: Callable[[S], T], items: Iterator[S], prefetch: int, workers: int = 1
) -> Iterator[T]:
    """Yield ``job(item)`` for every item in order, with ``job`` running in ``workers``
    background threads (named ``tum-prefetch-*``) up to ``prefetch`` items ahead. ``items`` is
    advanced in the caller's thread; an error of ``job`` is raised here, at the item that failed.
    Closing the generator cancels the jobs not started yet and waits for the running ones."""
    with ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="tum-prefetch") as pool:
        pending: deque[Future[T]] = deque(
            pool.submit(job, item) for item in itertools.islice(items, max(1, prefetch))
        )
        try:
            while pending:
                result = pending.popleft().result()
                nxt = next(items, _END)
                if nxt is not _END:
                    pending.append(pool.submit(job, nxt))
                yield result
        finally:
            for future in pending:
                future.cancel()


_END = object()


def _check_stride(stride: int, left: int, available: int, path: Path, minimum: int) -> None:
    """A ``stride`` > 1 that leaves fewer than ``minimum`` of the ``available`` frames (from
    ``sequence.start`` on) is one line naming ``sequence.stride``."""
    if stride > 1 and 0 < left < minimum:
        largest = max(1, (available - 1) // (minimum - 1))
        raise UssSlamError(
            f"sequence.stride={stride}: leaves {left} of the {available} associated frames of "
            f"{path}; expected at least {minimum} (a stride of at most {largest})"
        )


def _identity(frame: Frame) -> Frame:
    return frame


def read_labels(path: Path, shape: tuple[int, ...], image_name: str) -> np.ndarray:
    """The uint8 class-id PNG ``path`` of colour image ``image_name`` of ``(H, W)`` ``shape``,
    checked (errors name the file and what was expected; a value that is not a class id or
    255 too)."""
    labels = read_label_image(path)
    if labels.shape != tuple(shape):
        raise DataFormatError(
            path,
            f"labels are {labels.shape[1]}x{labels.shape[0]} but the colour image "
            f"{image_name} is {shape[1]}x{shape[0]}",
        )
    return labels

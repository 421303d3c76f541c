"""TUM RGB-D sequence reader: rgb/depth association, camera resolution, prefetched frame loading.

A sequence folder holds ``rgb.txt``, ``depth.txt``, optionally ``groundtruth.txt``, the images
they list, optionally ``intrinsics.yaml`` (our synthetic sequences) and ``labels/`` (uint8 class-id
PNGs named as the ``rgb/`` files). Colour frames are matched to depth frames as TUM's
``associate.py`` does (nearest stamp, at most ``max_diff`` seconds); a colour frame without a
depth partner is not silently dropped: it is counted in :attr:`TumSequence.unmatched_rgb`.
"""

from __future__ import annotations

import itertools
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
from uss_slam.core.tum_io import (
    TUM_CAMERAS,
    CameraIntrinsics,
    StrPath,
    Trajectory,
    associate,
    read_file_list,
    read_trajectory,
)

T = TypeVar("T")

INTRINSICS_FILE = "intrinsics.yaml"
LABELS_DIR = "labels"


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


def resolve_camera(
    spec: str | None, sequence_dir: Path, image_size: tuple[int, int]
) -> tuple[CameraIntrinsics, str]:
    """The camera for ``sequence.camera=spec`` and a short description of where it came from.

    ``None``/``"auto"``: the sequence's ``intrinsics.yaml`` if present, else TUM fr3.
    ``"fr1" | "fr2" | "fr3"``: TUM's published calibration (with distortion for fr1/fr2), rescaled
    when the images are not 640×480. Anything else is a path to an ``intrinsics.yaml``-format file,
    which must match the image size exactly. ``image_size`` is ``(width, height)``.
    """
    width, height = image_size
    if spec is None or str(spec).strip().lower() in ("", "auto", "none", "null"):
        own = sequence_dir / INTRINSICS_FILE
        if own.is_file():
            return _checked(CameraIntrinsics.from_yaml(own), own, image_size), str(own)
        spec = "fr3"
    name = str(spec).strip()
    if name.lower() in TUM_CAMERAS:
        cam = TUM_CAMERAS[name.lower()]
        if (cam.width, cam.height) != (width, height):
            cam = cam.scaled(width, height)
        return cam, name.lower()
    path = Path(name).expanduser()
    if not path.exists():
        raise UssSlamError(
            f"sequence.camera={name!r}: not one of {', '.join(sorted(TUM_CAMERAS))} "
            f"and no such file (expected a camera name or a path to an {INTRINSICS_FILE})"
        )
    if path.is_dir():
        raise DataFormatError(path, f"is a folder; expected an {INTRINSICS_FILE}-format file")
    return _checked(CameraIntrinsics.from_yaml(path), path, image_size), str(path)


def _checked(cam: CameraIntrinsics, path: Path, image_size: tuple[int, int]) -> CameraIntrinsics:
    if (cam.width, cam.height) != image_size:
        raise DataFormatError(
            path,
            f"camera is {cam.width}x{cam.height} but the sequence's images are "
            f"{image_size[0]}x{image_size[1]}",
        )
    return cam


class TumSequence:
    """A TUM RGB-D sequence on disk.

    Args:
        path: the sequence folder.
        camera: ``None``/``"auto"``, ``"fr1" | "fr2" | "fr3"`` or a path (see :func:`resolve_camera`).
        max_diff: largest rgb/depth stamp difference accepted by the association, seconds.
        load_labels: also load ``labels/<rgb file name>`` with every frame (oracle segmentation).
        start, stride, max_frames: which associated frames to use (``max_frames`` None = all).

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
    ) -> None:
        self.path = Path(path).expanduser()
        if not self.path.is_dir():
            raise DataFormatError(
                self.path, "not a folder; expected a TUM RGB-D sequence with rgb.txt and depth.txt"
            )
        if stride < 1 or start < 0 or (max_frames is not None and max_frames < 1):
            raise UssSlamError(
                f"sequence: start must be >= 0, stride >= 1 and max_frames >= 1 or null "
                f"(got start={start}, stride={stride}, max_frames={max_frames})"
            )
        rgb = read_file_list(self.path / "rgb.txt")
        depth = read_file_list(self.path / "depth.txt")
        if len(rgb) == 0:
            raise DataFormatError(rgb.path, "lists no images")
        i, j = associate(rgb.stamps, depth.stamps, max_difference=max_diff)
        if len(i) == 0:
            raise DataFormatError(
                depth.path,
                f"no depth stamp within {max_diff} s of any stamp in {rgb.path.name} "
                "(rgb and depth do not associate)",
            )
        self.max_diff = max_diff
        self.unmatched_rgb = len(rgb) - len(i)
        """Colour frames without a depth frame within ``max_diff`` (not processed, reported)."""
        self.load_labels = load_labels
        labels_dir = self.path / LABELS_DIR
        if load_labels and not labels_dir.is_dir():
            raise DataFormatError(
                labels_dir,
                "folder not found; segmenter=labels needs the sequence's labels/ folder "
                "(uint8 class-id PNGs named as the rgb/ files)",
            )
        records = []
        for k, (a, b) in enumerate(zip(i.tolist(), j.tolist(), strict=True)):
            rgb_path = rgb.resolve(a)
            records.append(
                FrameRecord(
                    index=k,
                    stamp=float(rgb.stamps[a]),
                    rgb_path=rgb_path,
                    depth_stamp=float(depth.stamps[b]),
                    depth_path=depth.resolve(b),
                    labels_path=labels_dir / rgb_path.name if load_labels else None,
                )
            )
        selected = records[start::stride]
        if max_frames is not None:
            selected = selected[:max_frames]
        if not selected:
            raise UssSlamError(
                f"sequence {self.path}: start={start} is past the {len(records)} associated frames"
            )
        self.records: list[FrameRecord] = [
            FrameRecord(k, r.stamp, r.rgb_path, r.depth_stamp, r.depth_path, r.labels_path)
            for k, r in enumerate(selected)
        ]
        for record in self.records:
            self._check_exists(record.rgb_path, rgb.path)
            self._check_exists(record.depth_path, depth.path)
            if record.labels_path is not None:
                self._check_exists(record.labels_path, labels_dir)
        first = cv2.imread(str(self.records[0].rgb_path), cv2.IMREAD_GRAYSCALE)
        if first is None:
            raise DataFormatError(self.records[0].rgb_path, "not a readable image")
        self.image_size: tuple[int, int] = (first.shape[1], first.shape[0])
        """``(width, height)`` of every frame, pixels."""
        self.camera, self.camera_source = resolve_camera(camera, self.path, self.image_size)
        self.load(0)  # format checks of the first frame before any work starts
        gt_path = self.path / "groundtruth.txt"
        self.groundtruth: Trajectory | None = (
            read_trajectory(gt_path) if gt_path.is_file() else None
        )

    @staticmethod
    def _check_exists(image: Path, listed_in: Path) -> None:
        if not image.is_file():
            raise DataFormatError(image, f"file not found (listed in {listed_in})")

    def __len__(self) -> int:
        return len(self.records)

    @property
    def stamps(self) -> np.ndarray:
        """``(N,)`` colour stamps of the selected frames, seconds."""
        return np.array([r.stamp for r in self.records])

    def load(self, index: int) -> Frame:
        """Read frame ``index`` from disk, checking formats and sizes (errors name the file)."""
        wall, cpu = time.perf_counter(), time.thread_time()
        record = self.records[index]
        bgr = cv2.imread(str(record.rgb_path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DataFormatError(record.rgb_path, "not a readable image")
        raw = cv2.imread(str(record.depth_path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise DataFormatError(record.depth_path, "not a readable image")
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise DataFormatError(
                record.depth_path,
                f"expected a single-channel uint16 depth PNG, got {raw.dtype} with shape {raw.shape}",
            )
        if raw.shape != bgr.shape[:2]:
            raise DataFormatError(
                record.depth_path,
                f"depth image is {raw.shape[1]}x{raw.shape[0]} but the colour image "
                f"{record.rgb_path.name} is {bgr.shape[1]}x{bgr.shape[0]}",
            )
        depth = raw.astype(np.float32) * np.float32(1.0 / self.camera.depth_scale)
        labels = None
        if record.labels_path is not None:
            labels = cv2.imread(str(record.labels_path), cv2.IMREAD_UNCHANGED)
            if labels is None:
                raise DataFormatError(record.labels_path, "not a readable image")
            if labels.dtype != np.uint8 or labels.ndim != 2:
                raise DataFormatError(
                    record.labels_path,
                    f"expected a single-channel uint8 class-id PNG, got {labels.dtype} "
                    f"with shape {labels.shape}",
                )
            if labels.shape != bgr.shape[:2]:
                raise DataFormatError(
                    record.labels_path,
                    f"labels are {labels.shape[1]}x{labels.shape[0]} but the colour image "
                    f"{record.rgb_path.name} is {bgr.shape[1]}x{bgr.shape[0]}",
                )
        if (bgr.shape[1], bgr.shape[0]) != self.image_size:
            raise DataFormatError(
                record.rgb_path,
                f"image is {bgr.shape[1]}x{bgr.shape[0]} but the sequence's first frame is "
                f"{self.image_size[0]}x{self.image_size[1]}",
            )
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        spent = (time.perf_counter() - wall, time.thread_time() - cpu)
        return Frame(record.index, record.stamp, rgb, gray, depth, labels, spent)

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

        with ThreadPoolExecutor(
            max_workers=max(1, workers), thread_name_prefix="tum-prefetch"
        ) as pool:
            upcoming = iter(range(len(self)))
            pending: deque[Future[T]] = deque(
                pool.submit(job, k) for k in itertools.islice(upcoming, prefetch)
            )
            try:
                while pending:
                    item = pending.popleft().result()
                    nxt = next(upcoming, None)
                    if nxt is not None:
                        pending.append(pool.submit(job, nxt))
                    yield item
            finally:
                for future in pending:
                    future.cancel()


def _identity(frame: Frame) -> Frame:
    return frame

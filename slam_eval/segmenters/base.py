"""Where per-pixel class labels come from during a SLAM run.

A segmenter turns a frame into ``(H, W)`` uint8 project class ids (``classes.CLASS_NAMES``) or
None. Image segmenters implement :meth:`ImageSegmenter.infer` on the RGB image alone (the ONNX
runtime segmenter of ``uss-export`` models is one); the oracle :class:`LabelsSegmenter` returns the
ground-truth ``labels/`` PNG that the sequence reader loaded with the frame.

Plugging in a segmenter: subclass :class:`ImageSegmenter`, give it a ``name`` and implement
``infer``; add ``configs/segmenter/<option>.yaml`` whose ``_target_`` is the class and whose other
keys are its constructor's keyword arguments (``uss-slam segmenter=<option> segmenter.<arg>=...``);
raise :class:`~uss_slam.core.errors.UssSlamError` for bad arguments or files (``uss-slam``
prints it as one line and exits 1). When it runs is the pipeline's business (``segment=every_frame``:
every frame, in ``slam.workers`` prefetch threads at once, so ``infer`` must be thread-safe;
``segment=keyframes``: keyframes only, in the main thread; see :mod:`..systems.harness`). A segmenter
that times stages of its own offers ``stage_times() -> {stage: (wall_s, cpu_s)}`` for the calling
thread's last call; the pipeline adds them as timing rows ``segmentation.<stage>`` (the ONNX
segmenter's dense CRF: ``segmentation.crf``).
"""

from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod
from typing import Annotated, Protocol, runtime_checkable

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.ranges import Range

from ..sequence import Frame


@runtime_checkable
class Segmenter(Protocol):
    """Anything that labels a frame: ``segment(frame) -> (H, W) uint8 class ids | None``."""

    name: str
    needs_labels: bool
    """True when the sequence reader must load the ``labels/`` folder for it."""

    def segment(self, frame: Frame) -> np.ndarray | None: ...


class ImageSegmenter(ABC):
    """A segmenter that sees only the RGB image; subclasses implement :meth:`infer`."""

    name = "image"
    needs_labels = False

    @abstractmethod
    def infer(self, rgb: np.ndarray) -> np.ndarray:
        """``(H, W, 3)`` uint8 RGB -> ``(H, W)`` uint8 project class ids, same size."""

    def segment(self, frame: Frame) -> np.ndarray:
        """``infer`` on the frame's RGB image, checked: ``(H, W)`` uint8 of the frame's size."""
        labels = np.asarray(self.infer(frame.rgb))
        if labels.shape != frame.gray.shape or labels.dtype != np.uint8:
            raise UssSlamError(
                f"segmenter {self.name!r} returned labels of shape {labels.shape} and dtype "
                f"{labels.dtype} for a frame of shape {frame.gray.shape}; expected "
                f"{frame.gray.shape} uint8 class ids"
            )
        return labels


class NoSegmenter:
    """No segmentation: filters that need labels cannot be used."""

    name = "none"
    needs_labels = False

    def segment(self, frame: Frame) -> None:
        return None


class LabelsSegmenter:
    """Oracle: the sequence's own ``labels/`` PNG (exact class ids of the synthetic world).

    ``latency_s`` (s, >= 0): behave as a network that takes that long per frame. With ``wait``
    false (the default) the latency is simulated: :attr:`simulated_latency_s` tells
    ``segment=thread`` to deliver each mask ``latency_s`` of camera time after it was asked for
    (deterministic, :mod:`..systems.semantic_thread`); the other schedules refuse a simulated
    latency. With ``wait`` true every call really sleeps ``latency_s`` (any schedule; it costs no
    CPU, unlike a network)."""

    name = "labels"
    needs_labels = True

    def __init__(self, latency_s: Annotated[float, Range(min=0)] = 0.0, wait: bool = False) -> None:
        if not latency_s >= 0:  # the schema checks the config; this, direct callers
            raise UssSlamError(f"segmenter.latency_s: expected a number >= 0, got {latency_s!r}")
        self.latency_s = float(latency_s)
        self.wait = bool(wait)

    @property
    def simulated_latency_s(self) -> float | None:
        """The latency the schedule simulates (s), or None when calls really wait."""
        return None if self.wait else self.latency_s

    def segment(self, frame: Frame) -> np.ndarray:
        if frame.labels is None:
            raise UssSlamError(
                "segmenter=labels but the frame has no labels: open the sequence with "
                "load_labels=True"
            )
        if self.wait and self.latency_s > 0:
            time.sleep(self.latency_s)
        return frame.labels


class LabelsOnce:
    """``segmenter`` with each frame's labels kept after its first call, for the repeats of one
    run (``slam.reuse_labels``): a later call on the same frame (by ``frame.index``) returns the
    kept labels instead of segmenting again. The labels are read-only arrays, so that no filter
    can change what a later repeat gets. ``stage_times()`` is the segmenter's for a call that
    segmented and empty for one that reused (nothing ran). Thread-safe as the segmenter is: the
    prefetch threads ask for different frames."""

    def __init__(self, segmenter: Segmenter) -> None:
        self.segmenter = segmenter
        self.name = segmenter.name
        self.needs_labels = segmenter.needs_labels
        self._kept: dict[int, np.ndarray | None] = {}
        self._local = threading.local()

    def segment(self, frame: Frame) -> np.ndarray | None:
        if frame.index in self._kept:
            self._local.reused = True
            return self._kept[frame.index]
        self._local.reused = False
        labels = self.segmenter.segment(frame)
        if labels is not None:
            labels = np.asarray(labels)
            labels.flags.writeable = False
        self._kept[frame.index] = labels
        return labels

    def stage_times(self) -> dict[str, tuple[float, float]]:
        stage_times = getattr(self.segmenter, "stage_times", None)
        if getattr(self._local, "reused", False) or stage_times is None:
            return {}
        return dict(stage_times())

    def forget(self) -> None:
        """Drop the kept labels (their memory); later calls segment again."""
        self._kept.clear()


def worth_keeping(segmenter: Segmenter) -> bool:
    """Whether :class:`LabelsOnce` saves work for ``segmenter``: not for no segmenter or the
    ground-truth labels, which cost nothing to get again."""
    return not isinstance(segmenter, NoSegmenter | LabelsSegmenter)


def class_ids(names: list[str] | tuple[str, ...], key: str | None = None) -> np.ndarray:
    """Project class ids of class names (errors name ``key``, the setting that lists them, and
    the known names)."""
    ids = []
    for name in names:
        if name not in CLASS_NAMES:
            raise UssSlamError(
                (f"{key}: " if key else "")
                + f"unknown class {name!r}; the project's classes are {', '.join(CLASS_NAMES)}"
            )
        ids.append(CLASS_NAMES.index(name))
    return np.asarray(ids, dtype=np.uint8)

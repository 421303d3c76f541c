"""``segment=thread`` for ORB-SLAM3: a slow segmenter's masks, one every ``latency_s`` of camera
time, carried to the frames in between by ORB-SLAM3's own tracked poses and blanked in its input.

ORB-SLAM3 takes masks only as blanked input pixels (:mod:`.masking`), decided before the frame
is tracked, and the ``pyorbslam3`` binding reports neither its keyframes nor a way to mark its
map points bad. The nearest scheme to the harness's semantic thread
(:mod:`~..semantic_thread`) it allows, on the same camera clock (frames arrive at their stamps;
deterministic, the same on a loaded machine):

- **Which frames are segmented** (:func:`schedule`, from the stamps alone): the first frame is
  segmented while tracking waits (as the harness waits for its first keyframe's mask), so that
  ORB-SLAM3 initialises its map on a masked frame. The thread then segments frame 1; a mask
  started on a frame of stamp ``t`` arrives at the first frame whose stamp is at least
  ``t + latency_s``, and the thread starts at once on that frame (one segmentation at a time).
- **How a mask is carried** (:class:`Carrier`): the segmented frame's labelled pixels, back-
  projected with its depth (holes inside a labelled region filled:
  :func:`~..semantic_thread.fill_depth`) from the pose ORB-SLAM3 tracked for it, are projected
  into each later frame with the pose ORB-SLAM3 tracked for the frame before it (the frame
  itself is not tracked yet) and splatted (:class:`~..semantic_thread.CarriedMask`, the
  harness's carrying). The carried labels go through the same filters as per-frame masks
  (:func:`~.masking.dynamic_mask`: the semantic filter's dilated dynamic classes) and are
  blanked in the frame's input.

How it differs from the harness's thread: (1) it segments a frame every ``latency_s`` s whatever
ORB-SLAM3 does with it, not the newest keyframe waiting (the binding does not say which frames
become keyframes); (2) a mask, once it arrives, only blanks later frames: the map points that
ORB-SLAM3 made from the people before it came stay in its map (the harness marks the points its
keyframe sees inside the mask bad), and nothing is refined after tracking (the harness drops
the flagged keypoints and refines the pose again); (3) the carrying pose is the previous
frame's, not the frame's own, and the segmented frame's pose is the one tracked then, not one
the back end moved since; (4) a segmented frame without a pose (not tracked) gives no mask: the
last one stays. ORB-SLAM3 may also start a new map after losing track; poses of different maps
are not told apart here.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...filters.base import DynamicFilter
from ...segmenters.base import Segmenter
from ...sequence import Frame, TumSequence
from ..semantic_thread import CarriedMask
from .masking import MaskPass, dynamic_mask, segment_timed


@dataclass(frozen=True)
class Schedule:
    """Which frames are segmented (``segmented``, positions in the sequence, ascending) and the
    position of the frame each one's mask reaches first (``delivered``, same length; the
    sequence's length when it never does). The first entry is frame 0, delivered at 0 (the
    wait)."""

    segmented: tuple[int, ...]
    delivered: tuple[int, ...]
    latency_s: float


def schedule(stamps: Sequence[float], latency_s: float) -> Schedule:
    """The camera-clock schedule of a thread whose segmentations take ``latency_s`` s each, for
    frames at ``stamps`` (s, ascending): see the module docstring."""
    n = len(stamps)
    segmented, delivered = [0], [0]
    i = 1
    while i < n:
        done = stamps[i] + latency_s
        j = i + 1  # latency 0: the next frame (a one-frame delay)
        while j < n and stamps[j] < done - 1e-9:
            j += 1
        segmented.append(i)
        delivered.append(j)
        i = j
    return Schedule(tuple(segmented), tuple(delivered), float(latency_s))


@dataclass
class Carrier:
    """The worker's side of the thread: per frame, the pixels to blank (:meth:`region`), then
    what ORB-SLAM3 tracked (:meth:`tracked`). ``labels`` maps each segmented position to its
    ``(H, W)`` uint8 labels; ``k`` (3, 3) the camera matrix; ``masks`` the filters whose pixels
    are blanked."""

    plan: Schedule
    labels: dict[int, np.ndarray]
    k: np.ndarray
    masks: Sequence[DynamicFilter]
    carried: tuple[CarriedMask, np.ndarray] | None = None
    """The mask being carried and its frame's pose (4, 4, world-from-camera)."""
    last_pose_wc: np.ndarray | None = None
    delivered: int = 0
    _arriving: dict[int, list[int]] = field(default_factory=dict)
    _waiting: dict[int, tuple[CarriedMask, np.ndarray] | None] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for seg, at in zip(self.plan.segmented, self.plan.delivered, strict=True):
            self._arriving.setdefault(at, []).append(seg)

    def region(self, frame: Frame) -> np.ndarray | None:
        """``(H, W)`` bool pixels of ``frame`` (position ``frame.index``) to blank, or None: its
        own mask at position 0 (the wait), else the latest mask arrived by now, carried by the
        previous tracked pose."""
        if frame.index == 0 and 0 in self.labels:
            self.delivered += 1
            return dynamic_mask(frame, self.labels[0], self.masks)
        for seg in self._arriving.get(frame.index, []):
            got = self._waiting.pop(seg, None)
            if got is not None:
                self.carried = got
                self.delivered += 1
        if self.carried is None or self.last_pose_wc is None:
            return None
        mask, pose_wc = self.carried
        labels = mask.labels_at(np.linalg.inv(self.last_pose_wc) @ pose_wc)
        return dynamic_mask(frame, labels, self.masks)

    def tracked(self, frame: Frame, pose_wc: np.ndarray | None) -> None:
        """ORB-SLAM3's pose of ``frame`` (4, 4 world-from-camera; None: not tracked): the
        carrying pose of the next frame, and for a segmented frame, its mask's pose."""
        if pose_wc is None:
            if frame.index in self.labels:
                self._waiting[frame.index] = None
            return
        pose_wc = np.asarray(pose_wc, np.float64)
        self.last_pose_wc = pose_wc
        if frame.index in self.labels:
            mask = CarriedMask.of(frame.index, self.labels[frame.index], frame.depth, self.k)
            if frame.index == 0:  # the waited mask blanked frame 0: carried from frame 1 on
                self.carried = (mask, pose_wc)
            else:
                self._waiting[frame.index] = (mask, pose_wc)


@dataclass(frozen=True)
class ThreadSpec:
    """``segment=thread`` for ORB-SLAM3: the segmenter's simulated ``latency_s`` and the
    filters whose pixels are blanked (``filters``, their ``filter_params``: the worker process
    builds them again)."""

    latency_s: float
    filters: list[str]
    filter_params: dict[str, Any]


def prepare(
    spec: ThreadSpec, sequence: TumSequence, segmenter: Segmenter, path: Path
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Segment the frames of the schedule (:func:`schedule`) into ``path`` (``.npz``); returns
    the worker job's ``thread`` entry and the run's figures (``latency_s``, ``segmented``,
    ``segmentation_ms`` per call, ``first_wait_s``)."""
    plan = schedule(list(sequence.stamps), spec.latency_s)
    frames = sequence.frames()
    try:
        ms, count = segment_scheduled(frames, plan, segmenter, path)
    finally:
        frames.close()
    job = {
        "labels": str(path),
        "segmented": list(plan.segmented),
        "delivered": list(plan.delivered),
        "latency_s": plan.latency_s,
        "k": np.asarray(sequence.camera.matrix, np.float64).tolist(),
        "filters": list(spec.filters),
        "filter_params": spec.filter_params,
    }
    figures = {
        "latency_s": plan.latency_s,
        "segmented": count,
        "segmentation_ms": ms,
        "first_wait_s": plan.latency_s,
    }
    return job, figures


def segment_scheduled(
    frames: Iterable[Frame], plan: Schedule, segmenter: Segmenter, path: Path
) -> tuple[float, int]:
    """Segment the frames of ``plan`` (``frames``: the sequence's frames, in order) and save
    their labels to ``path`` (``.npz``, one array ``f<position>`` each); returns the mean wall
    milliseconds per segmentation and how many."""
    wanted = set(plan.segmented)
    out: dict[str, np.ndarray] = {}
    spent = 0.0
    for frame in frames:
        if frame.index not in wanted:
            continue
        labels, seconds = segment_timed(segmenter, frame)
        spent += seconds
        out[f"f{frame.index}"] = np.asarray(labels, np.uint8)
    np.savez_compressed(path, **out)
    return 1000 * spent / max(len(out), 1), len(out)


def read_labels(path: str | Path) -> dict[int, np.ndarray]:
    """The labels :func:`segment_scheduled` saved, by position."""
    with np.load(path) as data:
        return {int(name[1:]): data[name] for name in data.files}


def thread_pass(figures: dict[str, Any], results: Sequence[Any], size: tuple[int, int]) -> MaskPass:
    """The run's :class:`~.masking.MaskPass` figures (``size`` = (W, H)): the mean blanked
    fraction over the repeats (each repeat's ``thread`` figures, as its worker reported them)
    and the segmenter's mean milliseconds per call; ``figures`` gains the masks ``delivered``
    per repeat and the mean ``carry_ms`` per frame."""
    got = [r.thread for r in results if r.thread]
    figures["delivered"] = [g["delivered"] for g in got]
    figures["carry_ms"] = float(np.mean([g["carry_ms"] for g in got])) if got else 0.0
    fraction = float(np.mean([g["blanked_fraction"] for g in got])) if got else 0.0
    width, height = size
    return MaskPass(
        np.zeros((0, 0), np.uint8), (height, width), fraction, figures["segmentation_ms"]
    )

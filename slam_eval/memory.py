"""The memory a ``uss-slam`` run holds, estimated from its settings before its first frame
(:func:`check_slam_memory`: one line naming the keys that drive it when it cannot fit; the
comparison and the ``USS_SLAM_NO_MEMORY_CHECK=1`` opt-out are
:func:`~uss_slam.core.resources.check_memory`'s).

A run holds, beyond what the process holds when the check runs (the imports, the segmenter's
weights once loaded: ``VmRSS``):

- **frames read ahead**: ``slam.prefetch`` frames plus one per ``slam.workers`` thread being
  prepared (at most the sequence's frames), each its colour, grey, depth and label images and
  its features (:data:`FRAME_BYTES_PER_PIXEL` × W × H);
- **the map**: keyframes (features, sub-sampled depth), map points and the per-frame log grow
  with the frames of the sequence (:data:`MAP_BYTES_PER_FRAME_PIXEL` × W × H per frame, measured
  at the default feature budget and scaled with ``slam.orb.n_features``);
- **the segmenter**: an exported model's weights (:data:`WEIGHT_COPIES` × its file: the file
  read, the session's initialisers, their pre-packed copies), and its runtime arena for one
  image (:data:`ARENA_BYTES_PER_PIXEL` × W × H) per concurrent inference (``slam.workers`` with
  ``segment=every_frame`` and ``slam.parallel``), plus :data:`THREAD_BYTES` per
  ``segmenter.threads`` thread;
- **repeats**: with ``slam.repeats`` > 1 each repeat's result (its point cloud and log) is kept
  until the median is chosen, and with ``slam.reuse_labels`` the labels of every frame (W × H
  bytes each);
- **a worker process** with ``slam.prefetch_mode=process`` (its own imports and threads:
  :data:`PROCESS_BYTES`), and its ring of shared memory (:func:`~.frontend.process.ring_bytes`);
- what the back end, OpenCV and the report's figures add whatever the frames
  (:data:`RUNTIME_BYTES`).

Comparison sets (``compare``) and repeats run one after the other: the map is held once at a
time (jobs a joblib multirun runs at once each count: ``check_memory``). The constants come from
measured peaks (``studies/memory_peaks.py``; docs/results/reliability.md), about doubled, and
the sum gets :data:`MARGIN` more.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2

from uss_slam.core.errors import DataFormatError
from uss_slam.core.images import read_image
from uss_slam.core.resources import check_memory, estimate_line, gigabytes

from .frontend.process import resolve_mode, ring_bytes

FRAME_BYTES_PER_PIXEL = 12
"""A frame read ahead: RGB (3) + grey (1) + depth float32 (4) + labels (1) bytes per pixel, its
features and the decoder's buffers (measured: ``slam.prefetch=256`` over the default on 200
real 640x480 frames, all of them held: 1.8 MB, 5.9 bytes per pixel; twice that)."""
MAP_BYTES_PER_FRAME_PIXEL = 1.0
"""Map, log and point cloud per frame of the sequence, per pixel of its images, at
:data:`REFERENCE_FEATURES` features (measured: 200 against 50 real 640x480 frames, 0.43 bytes
per pixel per frame; twice that)."""
REFERENCE_FEATURES = 1000
WEIGHT_COPIES = 4
"""An exported model's weights: the file read, the session's initialisers, their pre-packed
copies, and one spare."""
ARENA_BYTES_PER_PIXEL = 400
"""Activations of one inference of an exported segmenter per input pixel (measured: the small
DeepLab's export on 200 real 640x480 frames, two inferences at once, 4 threads and 3 repeats'
labels added 0.17 GB: under 280 bytes per pixel per inference; rounded up). A larger network's
activations per pixel are larger: its weights count by its file, its arena does not."""
THREAD_BYTES = 16 * 2**20
"""One ``segmenter.threads`` thread: its stack and the runtime's per-thread scratch."""
RESULT_BYTES_PER_FRAME = 64 * 2**10
"""A finished repeat's result kept until the median is chosen: its log and point cloud."""
PROCESS_BYTES = 256 * 2**20
"""The frame worker process of ``slam.prefetch_mode=process``: its own imports and threads
(measured with a comparison of three runs: 0.13 GB more over the process tree)."""
RUNTIME_BYTES = 128 * 2**20
"""What the run adds after the check whatever its frames: the back end's and OpenCV's buffers,
the report's figures (measured: 50 real 640x480 frames peak 70 MB above the check with 37 MB
of frames and map)."""
VOCABULARY_COPIES = 2
"""ORB-SLAM3's vocabulary in memory per byte of its text file (``system.vocabulary``): each node
of the tree (a 32-byte descriptor, its weight, its children's list) takes about what its text
line does; twice that."""
MASK_BYTES_PER_FRAME_PIXEL = 1
"""``system=orbslam3`` with a segmenter: every frame's dynamic mask, computed before the first
repeat (packed to a bit per pixel, one byte while it is computed)."""
MARGIN = 1.25
"""The allocator's and the libraries' share on top (fragmentation, OpenCV's and GTSAM's
buffers)."""


@dataclass(frozen=True)
class Part:
    """One part of the estimate: its bytes, the settings that drive it (``key=value``) and the
    keys to lower."""

    bytes: int  # noqa: A003
    keys: str
    lower: str


@dataclass(frozen=True)
class SlamMemory:
    """The estimate's parts by what they hold (``"frames read ahead"``, ``"the map"``, ...)."""

    parts: dict[str, Part]

    @property
    def need(self) -> int:
        """Bytes beyond what the process holds now (the parts with the margin)."""
        return int(MARGIN * (RUNTIME_BYTES + sum(p.bytes for p in self.parts.values())))

    def drivers(self) -> list[Part]:
        """The parts that make up at least a quarter of the estimate, largest first."""
        ranked = sorted(self.parts.values(), key=lambda p: -p.bytes)
        total = sum(p.bytes for p in ranked) or 1
        return [p for p in ranked if p.bytes >= total / 4] or ranked[:1]


def image_size(path: Path) -> tuple[int, int]:
    """(W, H) of an image file: a PNG's header, else the decoded image (one frame)."""
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        w, h = struct.unpack(">II", head[16:24])
        return int(w), int(h)
    try:
        image = read_image(path, cv2.IMREAD_UNCHANGED)
    except DataFormatError:
        return 0, 0
    return image.shape[1], image.shape[0]


def estimate(cfg: Any, frames: int, size: tuple[int, int]) -> SlamMemory:
    """The parts of a harness run of ``cfg`` over ``frames`` frames of ``size`` = (W, H) px
    (the sequence as selected: ``sequence.start``, ``stride``, ``max_frames``)."""
    slam, (w, h) = cfg.slam, size
    pixels = w * h
    workers, prefetch = int(slam.workers), int(slam.prefetch)
    ahead = min(prefetch + workers, frames) if bool(slam.parallel) else 1  # no more than it has
    parts = {"frames read ahead": Part(
        ahead * FRAME_BYTES_PER_PIXEL * pixels,
        f"slam.prefetch={prefetch}, slam.workers={workers}", "slam.prefetch")}  # fmt: skip
    parts["the map"] = _map_part(cfg, frames, size, int(slam.orb.n_features),
                                 "slam.orb.n_features")  # fmt: skip
    model = cfg.segmenter.get("path") if "segmenter" in cfg else None
    if model and Path(str(model)).is_file():
        every = str(cfg.get("segment", "every_frame")) == "every_frame" and bool(slam.parallel)
        inferences = workers if every else 1
        threads = int(cfg.segmenter.get("threads") or 1)
        parts["the segmenter"] = Part(
            WEIGHT_COPIES * Path(str(model)).stat().st_size
            + inferences * ARENA_BYTES_PER_PIXEL * pixels + threads * THREAD_BYTES,
            f"segmenter.threads={threads}" + (f", slam.workers={workers}" if every else ""),
            "segmenter.threads" + (" or slam.workers" if every else ""))  # fmt: skip
    repeats = int(slam.repeats)
    if repeats > 1:
        labels = frames * pixels if bool(slam.reuse_labels) and model else 0
        parts["repeats"] = Part(repeats * frames * RESULT_BYTES_PER_FRAME + labels,
                                f"slam.repeats={repeats}", "slam.repeats")  # fmt: skip
    mode = resolve_mode(str(slam.prefetch_mode), sample=False)  # auto: the process may run
    if mode == "process" and bool(slam.parallel) and prefetch > 0:
        ring = ring_bytes(h, w, prefetch)
        parts["the frame worker process"] = Part(
            PROCESS_BYTES + ring,
            f"slam.prefetch_mode={slam.prefetch_mode}",
            "slam.prefetch_mode=thread",
        )
    return SlamMemory(parts)


def _map_part(cfg: Any, frames: int, size: tuple[int, int], n_features: int, key: str) -> Part:
    """The map, the log and the point cloud of ``frames`` frames of ``size`` at ``n_features``."""
    (w, h) = size
    return Part(
        int(frames * MAP_BYTES_PER_FRAME_PIXEL * w * h
            * max(n_features, REFERENCE_FEATURES) / REFERENCE_FEATURES),
        f"sequence.path ({frames} frames of {w}x{h}), {key}={n_features}",
        "sequence.max_frames (or raise sequence.stride)")  # fmt: skip


def estimate_orbslam3(cfg: Any, frames: int, size: tuple[int, int]) -> SlamMemory:
    """The parts of a ``system=orbslam3`` run of ``cfg``, as :func:`estimate`'s for the harness:
    its worker process (:data:`PROCESS_BYTES`) holding the vocabulary
    (:data:`VOCABULARY_COPIES` × its file) and the map (as the harness's, at
    ``system.n_features``); with a segmenter, its weights and one inference at a time, and every
    frame's mask (:data:`MASK_BYTES_PER_FRAME_PIXEL`). Repeats run one after the other."""
    pixels = size[0] * size[1]
    vocabulary = Path(str(cfg.system.get("vocabulary") or ""))
    parts = {"the ORB-SLAM3 process": Part(PROCESS_BYTES, "system=orbslam3", "system.vocabulary")}
    if vocabulary.is_file():
        parts["the vocabulary"] = Part(
            VOCABULARY_COPIES * vocabulary.stat().st_size, f"system.vocabulary={vocabulary}",
            "system.vocabulary (a smaller one: uss-vocab build -k / -L)")  # fmt: skip
    parts["the map"] = _map_part(cfg, frames, size, int(cfg.system.n_features), "system.n_features")
    model = cfg.segmenter.get("path") if "segmenter" in cfg else None
    if model and Path(str(model)).is_file():
        threads = int(cfg.segmenter.get("threads") or 1)
        parts["the segmenter"] = Part(
            WEIGHT_COPIES * Path(str(model)).stat().st_size + ARENA_BYTES_PER_PIXEL * pixels
            + threads * THREAD_BYTES, f"segmenter.threads={threads}", "segmenter.threads")  # fmt: skip
    if str(cfg.segmenter.get("_target_", "")).rsplit(".", 1)[-1] != "NoSegmenter":
        parts["the masks"] = Part(frames * MASK_BYTES_PER_FRAME_PIXEL * pixels,
                                  f"sequence.path ({frames} frames), segmenter",
                                  "sequence.max_frames")  # fmt: skip
    return SlamMemory(parts)


def check_slam_memory(cfg: Any, sequence: Any, log: Any = None) -> None:
    """One line before the first frame when the run's estimate (:func:`estimate`) for
    ``sequence`` (a ``TumSequence``) exceeds the memory available, naming the settings of the
    parts that make up most of it; ``log`` (a logger) gets the estimate at DEBUG level: at INFO
    it would reach the run folder's ``run.log`` before the run is known to go ahead, and a run
    stopped then must leave the earlier run's files as they were. ``system=orbslam3`` is
    estimated by :func:`estimate_orbslam3`, the harness by :func:`estimate`."""
    frames = len(sequence)
    size = image_size(sequence.records[0].rgb_path) if frames else (0, 0)
    orbslam3 = str(cfg.get("system", {}).get("name", "harness")) == "orbslam3"
    memory = (estimate_orbslam3 if orbslam3 else estimate)(cfg, frames, size)
    if log is not None:
        log.debug(estimate_line(memory.need))
    drivers = memory.drivers()
    parts = ", ".join(f"{what} {gigabytes(p.bytes)}" for what, p in memory.parts.items())
    parts += f", the back end and the report {gigabytes(RUNTIME_BYTES)}"
    check_memory(memory.need, "; ".join(p.keys for p in drivers), f"this run ({parts})",
                 " or ".join(p.lower for p in drivers))  # fmt: skip

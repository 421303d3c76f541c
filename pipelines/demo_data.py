"""The demo data set: what ``uss-demo``'s ``data`` stage renders with :mod:`uss_slam.synthetic`.

Layout of ``OUT/data`` (what ``configs/data/synthetic.yaml`` reads from ``paths.data_dir``)::

    voc/VOCdevkit/VOC2012/             source-style VOC set (person, chair, monitor)
    target_train/<preset>/             target-style sequences, used unlabelled for adaptation
    target_val/walking_xyz/            target style, another seed: labelled validation frames
    slam/{walking_xyz,static_xyz}/     target style at SLAM size: the SLAM evaluation
    demo.yaml                          what made it (:meth:`DemoData.record`)

The folder appears only when complete (rendered into a hidden sibling, then renamed); its
``demo.yaml`` is the completion record.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from PIL import Image

from uss_slam.core.classes import CLASS_NAMES, voc_lut
from uss_slam.core.errors import UssSlamError
from uss_slam.core.progress import progress_bar
from uss_slam.core.tum_io import read_file_list
from uss_slam.synthetic import render_sequence, render_voc
from uss_slam.synthetic.output import check_size, staged_output
from uss_slam.synthetic.textures import WARDROBES

TRAIN_PRESETS = ("walking_xyz", "walking_rpy", "walking_halfsphere", "sitting_static")
"""Target training sequences (one seed each: ``seed + 1 + k``)."""
SLAM_PRESETS = ("walking_xyz", "static_xyz")
"""SLAM evaluation sequences (seed ``seed``)."""
VAL_PRESET = "walking_xyz"
VAL_SEED_OFFSET = 100
RECORD = "demo.yaml"
GENERATOR = "uss-synth demo"
"""The record's ``generator`` (kept from when ``uss-synth demo`` rendered it, so data sets
rendered then are still recognised and reused)."""


@dataclass(frozen=True)
class DemoData:
    """Everything the data set's content depends on; counts of 0 skip a part."""

    seed: int = 0
    voc_images: int = 400
    voc_size: tuple[int, int] = (320, 240)
    train_frames: int = 100
    val_frames: int = 100
    train_size: tuple[int, int] = (320, 240)
    slam_frames: int = 300
    slam_size: tuple[int, int] = (640, 480)
    source_outfits: str = "classic"  # the VOC set's people's clothing (synthetic.WARDROBES)

    def __post_init__(self) -> None:
        if self.source_outfits not in WARDROBES:
            raise UssSlamError(
                f"source_outfits must be one of {', '.join(WARDROBES)}, got {self.source_outfits!r}"
            )
        if self.voc_images < 0:
            raise UssSlamError(f"voc_images must be >= 0 (0 skips), got {self.voc_images}")
        for name in ("train_frames", "val_frames", "slam_frames"):
            value = getattr(self, name)
            if value < 0 or value == 1:
                raise UssSlamError(f"{name} must be 0 (skip) or >= 2, got {value}")
        for name in ("voc_size", "train_size", "slam_size"):
            check_size(getattr(self, name))

    def record(self) -> dict[str, Any]:
        """The content of ``demo.yaml`` (same keys and order as ever: old data sets match;
        ``source_outfits`` only when not ``classic``)."""
        record = {
            "generator": GENERATOR,
            "seed": self.seed,
            "voc_images": self.voc_images,
            "voc_size": list(self.voc_size),
            "train_frames": self.train_frames,
            "val_frames": self.val_frames,
            "train_size": list(self.train_size),
            "slam_frames": self.slam_frames,
            "slam_size": list(self.slam_size),
        }
        if self.source_outfits != "classic":
            record["source_outfits"] = self.source_outfits
        return record


def is_complete(out: Path, spec: DemoData) -> bool:
    """True when ``out`` holds a complete data set rendered from ``spec``."""
    try:
        return yaml.safe_load((Path(out) / RECORD).read_text()) == spec.record()
    except (OSError, yaml.YAMLError):
        return False


Task = tuple[str, Callable[..., Path], dict[str, Any]]


def _tasks(root: Path, spec: DemoData) -> list[Task]:
    tasks: list[Task] = []
    if spec.voc_images:
        tasks.append(("voc", render_voc, dict(out_dir=root / "voc", images=spec.voc_images,
                                              size=spec.voc_size, seed=spec.seed,
                                              outfits=spec.source_outfits)))  # fmt: skip
    if spec.train_frames:
        for k, preset in enumerate(TRAIN_PRESETS):
            tasks.append((f"target_train/{preset}", render_sequence, dict(
                out_dir=root / "target_train" / preset, preset=preset, frames=spec.train_frames,
                size=spec.train_size, seed=spec.seed + 1 + k, style="target")))  # fmt: skip
    if spec.val_frames:
        tasks.append((f"target_val/{VAL_PRESET}", render_sequence, dict(
            out_dir=root / "target_val" / VAL_PRESET, preset=VAL_PRESET, frames=spec.val_frames,
            size=spec.train_size, seed=spec.seed + VAL_SEED_OFFSET, style="target")))  # fmt: skip
    if spec.slam_frames:
        for preset in SLAM_PRESETS:
            tasks.append((f"slam/{preset}", render_sequence, dict(
                out_dir=root / "slam" / preset, preset=preset, frames=spec.slam_frames,
                size=spec.slam_size, seed=spec.seed, style="target")))  # fmt: skip
    return tasks


def _cost(kwargs: dict[str, Any]) -> float:
    """Rough rendering cost of a task (pixels times frames or images)."""
    w, h = kwargs["size"]
    return w * h * kwargs.get("frames", kwargs.get("images", 1)) * (2 if "frames" in kwargs else 1)


def render_demo_data(
    out: Path,
    spec: DemoData,
    *,
    overwrite: bool = False,
    workers: int | None = None,
    progress: bool = True,
) -> Path:
    """Render the data set into ``out`` (all-or-nothing) and return its path.

    The parts (the VOC set and each sequence) are independent tasks run on ``workers``
    processes (default ``min(2, CPUs)``); the files do not depend on the number of workers.
    ``overwrite`` replaces an existing uss-synth output folder once the new one is complete.
    """
    workers = min(2, os.cpu_count() or 1) if workers is None else workers
    if workers < 1:
        raise UssSlamError(f"workers must be >= 1, got {workers}")
    with staged_output(out, overwrite) as tmp:
        (tmp / RECORD).write_text(yaml.safe_dump(spec.record(), sort_keys=False))
        tasks = _tasks(tmp, spec)
        if workers <= 1 or len(tasks) <= 1:
            for _, fn, kwargs in tasks:
                fn(**kwargs, progress=progress)
        else:
            # biggest first, so that the long SLAM sequences do not start last
            tasks.sort(key=lambda task: -_cost(task[2]))
            with ProcessPoolExecutor(max_workers=workers) as pool:
                futures = [pool.submit(fn, **kwargs) for _, fn, kwargs in tasks]
                names = {f: name for f, (name, _, _) in zip(futures, tasks, strict=True)}
                bar = progress_bar(
                    total=len(futures), desc="demo parts", unit="part", disable=not progress
                )
                for future in as_completed(futures):
                    future.result()
                    bar.set_postfix_str(names[future])
                    bar.update()
                bar.close()
    return Path(out)


def _counts(labels: list[Path]) -> np.ndarray:
    counts = np.zeros(256, np.int64)
    for path in labels:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        counts += np.bincount(img.reshape(-1), minlength=256)
    return counts


def summarize(root: Path) -> str:
    """A human-readable summary of a data set folder: counts, sizes, class pixel shares."""
    lines = [f"demo data set in {Path(root).resolve()}"]

    def shares(counts: np.ndarray) -> str:
        valid = counts[: len(CLASS_NAMES)].sum()
        parts = [f"{n} {100 * counts[i] / max(valid, 1):.1f}%" for i, n in enumerate(CLASS_NAMES)]
        return ", ".join(parts)

    voc = root / "voc" / "VOCdevkit" / "VOC2012"
    if voc.is_dir():
        train = (voc / "ImageSets" / "Segmentation" / "train.txt").read_text().split()
        val = (voc / "ImageSets" / "Segmentation" / "val.txt").read_text().split()
        pngs = sorted((voc / "SegmentationClass").glob("*.png"))
        counts = np.zeros(256, np.int64)
        for p in pngs:
            counts += np.bincount(np.asarray(Image.open(p)).reshape(-1), minlength=256)
        ours = np.zeros(256, np.int64)
        np.add.at(ours, voc_lut(), counts)
        w, h = Image.open(pngs[0]).size
        void = 100 * counts[255] / counts.sum()
        lines.append(f"  voc/VOCdevkit/VOC2012: {len(train)} train + {len(val)} val images, {w}x{h}, "
                     f"source style; pixels: {shares(ours)} (void {void:.1f}%)")  # fmt: skip
    for group in ("target_train", "target_val", "slam"):
        folder = root / group
        if not folder.is_dir():
            continue
        for seq in sorted(p for p in folder.iterdir() if p.is_dir()):
            rgb = read_file_list(seq / "rgb.txt")
            labels = sorted((seq / "labels").glob("*.png"))
            counts = _counts(labels[:: max(1, len(labels) // 20)])
            first = cv2.imread(str(rgb.resolve(0)), cv2.IMREAD_UNCHANGED)
            meta = (seq / "synthetic.yaml").read_text() if (seq / "synthetic.yaml").exists() else ""
            style = "target" if "style: target" in meta else "source"
            lines.append(f"  {group}/{seq.name}: {len(rgb)} frames, {first.shape[1]}x{first.shape[0]}, "
                         f"{style} style; pixels: {shares(counts)}")  # fmt: skip
    return "\n".join(lines)

"""The synthetic data set recipe (:class:`DemoData`): what ``uss-demo``'s ``data`` stage and
``uss-experiments``' ``data`` stage render with :mod:`uss_slam.synthetic`.

Layout of ``OUT/data`` (what ``configs/data/synthetic.yaml`` reads from ``paths.data_dir``)::

    voc/VOCdevkit/VOC2012/             source-style VOC set (person, chair, monitor)
    target_train/<preset>/             target-style sequences, used unlabelled for adaptation
    target_val/{walking_xyz,walking_rpy}/  target style, other seeds: labelled validation frames
    slam/{walking_xyz,static_xyz}/     target style at SLAM size: the SLAM evaluation
    demo.yaml                          what made it (:meth:`DemoData.record`)

What source and target differ in is the *shift* (:data:`SHIFTS`):

- ``tum_like`` (default), the stand-in for VOC / SBD / COCO -> TUM: the source people wear the
  ``all`` wardrobe (every garment family of the world, in rooms of both material families), as
  real photos show every kind of clothing, and 30% of the source images face a person at the
  walkers' distance (:data:`SHIFT_NEAR`), as real photos show people at every distance; the
  target differs by lighting, sensor, viewpoint
  and distance, layout and class priors; each target sequence's walkers wear outfits drawn for
  that sequence from the same distribution (``outfits="drawn"``), so the evaluation
  sequences' outfits were never rendered for training or validation.
- ``appearance``: the target is the *same* content generator as the source (VOC layouts,
  materials, wardrobe, class frequencies) rendered with the target lighting and sensor; its
  frames are labelled image folders ``target_train/images_<k>/`` and ``target_val/images/``
  (:func:`~uss_slam.synthetic.voc.render_voc_frames`). The shift output-space adaptation is
  designed for: the methods' sanity check. Its SLAM sequences are the ``tum_like`` ones.
- ``full``: disjoint material families (the source's saturated prints against the target's
  office and its two outfit families, the same in every target sequence): the hard case, and
  what data sets made before shifts existed are.

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
from uss_slam.core.images import read_image
from uss_slam.core.paths import path_override
from uss_slam.core.processes import pool_ending_with_parent
from uss_slam.core.progress import progress_bar
from uss_slam.core.tum_io import read_file_list
from uss_slam.synthetic import render_sequence, render_voc
from uss_slam.synthetic.output import check_size, staged_output
from uss_slam.synthetic.textures import WARDROBES
from uss_slam.synthetic.voc import render_voc_frames

SHIFTS = ("tum_like", "appearance", "full")
"""The domain shifts of the synthetic world (module docstring); ``tum_like`` is the default."""
DEFAULT_SHIFT = "tum_like"
SHIFT_WARDROBE = {"tum_like": "all", "appearance": "classic", "full": "classic"}
"""The VOC set's wardrobe of each shift (``full`` can take another: ``source_outfits``)."""
SHIFT_OUTFITS = {"tum_like": "drawn", "appearance": "drawn", "full": "office"}
"""What the people of the target *sequences* wear under each shift
(:data:`~uss_slam.synthetic.sequence.SEQUENCE_OUTFITS`)."""
SHIFT_NEAR = {"tum_like": 0.3, "appearance": 0.0, "full": 0.0}
"""The share of the VOC set's images that face a person at walking distance under each shift
(:func:`~uss_slam.synthetic.voc.near_view`): real photos show people at every distance, the
TUM walkers' 0.6-1.6 m included; without them no source-trained segmenter finds the walkers."""
APPEARANCE_FOLDERS = 4
"""Target training image folders of the ``appearance`` shift (one seed each, as the four
training sequences of the others)."""


def check_shift(shift: str, key: str = "shift") -> str:
    """``shift`` if it is one of :data:`SHIFTS`, else a one-line error naming ``key``."""
    if shift not in SHIFTS:
        raise UssSlamError(f"{key}: unknown shift {shift!r}; expected one of {', '.join(SHIFTS)}")
    return shift


TRAIN_PRESETS = ("walking_xyz", "walking_rpy", "walking_halfsphere", "sitting_static")
"""Target training sequences (one seed each: ``seed + 1 + k``)."""
SLAM_PRESETS = ("walking_xyz", "static_xyz")
"""SLAM evaluation sequences (seed :attr:`DemoData.slam_seed`, else ``seed``)."""
VAL_PRESETS = ("walking_xyz", "walking_rpy")
"""Labelled target validation sequences (seed ``seed + VAL_SEED_OFFSET + k``): checkpoint
selection with target labels and the methods' hyper-parameters are chosen on all of them, so that
a choice is not fitted to one camera motion (one chosen on walking_xyz alone helped walking_xyz
and cost walking_rpy 6.5-8.1 mIoU points on every seed, docs/results/shifts.md)."""
VAL_SEED_OFFSET = 100


def sequence_seeds(seed: int) -> dict[str, int]:
    """The seed of each target training and validation sequence of a data set of ``seed``
    (``target_train/<preset>`` and ``target_val/<preset>``; the VOC set takes ``seed`` itself)."""
    train = {f"target_train/{p}": seed + 1 + k for k, p in enumerate(TRAIN_PRESETS)}
    val = {f"target_val/{p}": seed + VAL_SEED_OFFSET + k for k, p in enumerate(VAL_PRESETS)}
    return train | val


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
    # the VOC set's people's clothing (synthetic.WARDROBES); None: the shift's (SHIFT_WARDROBE)
    source_outfits: str | None = None
    shift: str = DEFAULT_SHIFT  # what source and target differ in (SHIFTS)
    # the SLAM sequences' own seed (None: ``seed``), so that they are renders no choice saw
    slam_seed: int | None = None

    def __post_init__(self) -> None:
        check_shift(self.shift)
        if self.source_outfits is not None and self.source_outfits not in WARDROBES:
            raise UssSlamError(
                f"source_outfits must be one of {', '.join(WARDROBES)}, got {self.source_outfits!r}"
            )
        if self.source_outfits not in (None, SHIFT_WARDROBE[self.shift]) and self.shift != "full":
            raise UssSlamError(
                f"source_outfits={self.source_outfits} is the shift's to choose: shift "
                f"{self.shift} dresses the source in {SHIFT_WARDROBE[self.shift]!r} (use shift "
                "full for another wardrobe)"
            )
        if self.voc_images < 0:
            raise UssSlamError(f"voc_images must be >= 0 (0 skips), got {self.voc_images}")
        for name in ("train_frames", "val_frames", "slam_frames"):
            value = getattr(self, name)
            if value < 0 or value == 1:
                raise UssSlamError(f"{name} must be 0 (skip) or >= 2, got {value}")
        for name in ("voc_size", "train_size", "slam_size"):
            check_size(getattr(self, name))
        if self.slam_seed is not None and self.slam_seed < 0:
            raise UssSlamError(f"slam_seed must be >= 0 (or None: seed), got {self.slam_seed}")

    @property
    def wardrobe(self) -> str:
        """The VOC set's wardrobe."""
        return self.source_outfits or SHIFT_WARDROBE[self.shift]

    @property
    def near(self) -> float:
        """The share of the VOC set's images at walking distance from a person."""
        return SHIFT_NEAR[self.shift]

    @property
    def sequence_outfits(self) -> str:
        """What the people of the target sequences wear."""
        return SHIFT_OUTFITS[self.shift]

    def target_folders(self) -> list[str]:
        """The target training folders, relative to the data set (unlabelled for training)."""
        if self.shift == "appearance":
            return [f"target_train/images_{k}" for k in range(APPEARANCE_FOLDERS)]
        return [f"target_train/{preset}" for preset in TRAIN_PRESETS]

    def val_folders(self) -> list[str]:
        """The labelled target validation folders, relative to the data set."""
        if self.shift == "appearance":
            return ["target_val/images"]
        return [f"target_val/{preset}" for preset in VAL_PRESETS]

    def train_overrides(self, root: Path) -> list[str]:
        """``uss-train`` overrides that point ``data=synthetic`` at this data set in ``root``
        (besides ``paths.data_dir``: the folders of shifts whose layout is not the shipped
        config's)."""
        if self.shift != "appearance":
            return []
        target = [Path(root) / f for f in self.target_folders()]
        val = [Path(root) / f for f in self.val_folders()]
        return [path_override("data.target.roots", target), path_override("data.val.roots", val)]

    def record(self) -> dict[str, Any]:
        """The content of ``demo.yaml`` (same keys and order as ever: old data sets match;
        ``source_outfits`` only when not ``classic``, ``shift`` only when not ``full``,
        ``source_near`` only when not 0; ``val_sequences`` whenever the validation frames are
        sequences, so a data set made when there was one validation sequence is rendered again
        rather than read without the others; ``slam_seed`` only when set)."""
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
        if self.wardrobe != "classic":
            record["source_outfits"] = self.wardrobe
        if self.shift != "full":
            record["shift"] = self.shift
        if self.near:
            record["source_near"] = self.near
        if self.val_frames and self.shift != "appearance":
            record["val_sequences"] = list(VAL_PRESETS)
        if self.slam_seed is not None:
            record["slam_seed"] = self.slam_seed
        return record


def read_spec(root: Path) -> DemoData:
    """The spec a data set at ``root`` was rendered from, read back from its ``demo.yaml``
    (records written before ``source_outfits`` and ``shift`` existed get their defaults)."""
    record = yaml.safe_load((Path(root) / RECORD).read_text(encoding="utf-8"))
    return DemoData(
        seed=record["seed"],
        voc_images=record["voc_images"],
        voc_size=tuple(record["voc_size"]),
        train_frames=record["train_frames"],
        val_frames=record["val_frames"],
        train_size=tuple(record["train_size"]),
        slam_frames=record["slam_frames"],
        slam_size=tuple(record["slam_size"]),
        source_outfits=record.get("source_outfits"),
        shift=record.get("shift", "full"),
        slam_seed=record.get("slam_seed"),
    )


def is_complete(out: Path, spec: DemoData) -> bool:
    """True when ``out`` holds a complete data set rendered from ``spec``: its record says so
    and every file its lists name is still there (a stage is complete only while its outputs
    exist: a frame deleted since renders the data set again)."""
    try:
        if yaml.safe_load((Path(out) / RECORD).read_text(encoding="utf-8")) != spec.record():
            return False
    except (OSError, yaml.YAMLError):
        return False
    return _files_present(Path(out))


def _files_present(root: Path) -> bool:
    """Whether every image the data set's lists name exists: each sequence's ``rgb.txt`` and
    ``depth.txt`` entries and their labels, each VOC image set's JPEG and label PNG."""
    from uss_slam.core.tum_io import read_tum_folder

    try:
        for lst in sorted(root.glob("*/*/rgb.txt")):
            seq = lst.parent
            folder = read_tum_folder(seq, depth=(seq / "depth.txt").is_file(),
                                     labels=(seq / "labels").is_dir())  # fmt: skip
            if any(folder.missing(frame) is not None for frame in folder.frames):
                return False
        for sets in sorted(root.glob("voc/**/ImageSets/Segmentation")):
            voc = sets.parents[1]
            for name in {
                n for f in sets.glob("*.txt") for n in f.read_text(encoding="utf-8").split()
            }:
                if not ((voc / "JPEGImages" / f"{name}.jpg").is_file()
                        and (voc / "SegmentationClass" / f"{name}.png").is_file()):  # fmt: skip
                    return False
    except (OSError, UssSlamError):
        return False
    return True


Task = tuple[str, Callable[..., Path], dict[str, Any]]


def _tasks(root: Path, spec: DemoData) -> list[Task]:
    tasks: list[Task] = []
    if spec.voc_images:
        tasks.append(("voc", render_voc, dict(out_dir=root / "voc", images=spec.voc_images,
                                              size=spec.voc_size, seed=spec.seed,
                                              outfits=spec.wardrobe, near=spec.near)))  # fmt: skip
    outfits = spec.sequence_outfits
    if spec.shift == "appearance":
        # the source's content generator in the target's lighting and sensor (other seeds)
        frames = dict(size=spec.train_size, outfits=spec.wardrobe, style="target")
        if spec.train_frames:
            for k, folder in enumerate(spec.target_folders()):
                tasks.append((folder, render_voc_frames, dict(
                    out_dir=root / folder, images=spec.train_frames, seed=spec.seed + 1 + k,
                    **frames)))  # fmt: skip
        if spec.val_frames:
            tasks.append((spec.val_folders()[0], render_voc_frames, dict(
                out_dir=root / spec.val_folders()[0], images=spec.val_frames,
                seed=spec.seed + VAL_SEED_OFFSET, **frames)))  # fmt: skip
    else:
        tasks += _sequence_tasks(root, spec, outfits)
    if spec.slam_frames:
        for preset in SLAM_PRESETS:
            tasks.append((f"slam/{preset}", render_sequence, dict(
                out_dir=root / "slam" / preset, preset=preset, frames=spec.slam_frames,
                size=spec.slam_size, seed=spec.seed if spec.slam_seed is None else spec.slam_seed,
                style="target", outfits=outfits)))  # fmt: skip
    return tasks


def _sequence_tasks(root: Path, spec: DemoData, outfits: str) -> list[Task]:
    tasks: list[Task] = []
    frames = {"target_train": spec.train_frames, "target_val": spec.val_frames}
    for folder, seed in sequence_seeds(spec.seed).items():
        group, preset = folder.split("/")
        if frames[group]:
            tasks.append((folder, render_sequence, dict(
                out_dir=root / folder, preset=preset, frames=frames[group],
                size=spec.train_size, seed=seed, style="target", outfits=outfits)))  # fmt: skip
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
        (tmp / RECORD).write_text(yaml.safe_dump(spec.record(), sort_keys=False), encoding="utf-8")
        tasks = _tasks(tmp, spec)
        if workers <= 1 or len(tasks) <= 1:
            for _, fn, kwargs in tasks:
                fn(**kwargs, progress=progress)
        else:
            # biggest first, so that the long SLAM sequences do not start last
            tasks.sort(key=lambda task: -_cost(task[2]))
            with ProcessPoolExecutor(max_workers=workers, **pool_ending_with_parent()) as pool:
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
        img = read_image(path, cv2.IMREAD_UNCHANGED, "a label image")
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
        train = (
            (voc / "ImageSets" / "Segmentation" / "train.txt").read_text(encoding="utf-8").split()
        )
        val = (voc / "ImageSets" / "Segmentation" / "val.txt").read_text(encoding="utf-8").split()
        pngs = sorted((voc / "SegmentationClass").glob("*.png"))
        counts = np.zeros(256, np.int64)
        for p in pngs:
            with Image.open(p) as label:
                counts += np.bincount(np.asarray(label).reshape(-1), minlength=256)
        ours = np.zeros(256, np.int64)
        np.add.at(ours, voc_lut(), counts)
        with Image.open(pngs[0]) as first:  # (closed: no ResourceWarning)
            w, h = first.size
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
            first = read_image(rgb.resolve(0), cv2.IMREAD_UNCHANGED, "a colour image")
            meta = (
                (seq / "synthetic.yaml").read_text(encoding="utf-8")
                if (seq / "synthetic.yaml").exists()
                else ""
            )
            style = "target" if "style: target" in meta else "source"
            lines.append(f"  {group}/{seq.name}: {len(rgb)} frames, {first.shape[1]}x{first.shape[0]}, "
                         f"{style} style; pixels: {shares(counts)}")  # fmt: skip
    return "\n".join(lines)

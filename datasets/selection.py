"""Source-set selection: which labelled images of VOC / SBD / COCO (or any labelled set) train.

:class:`SelectedSources` is the source dataset of a real-data run: the concatenation of the
configured sets after

1. bad input: items whose image or label cannot be read, is truncated, has values outside the
   known classes or a size different from its image are an error (``on_error: raise``) or left
   out and counted (``on_error: skip``);
2. overlap: SBD images that are in the VOC 2012 ``val`` split (``exclude_voc_val``) and SBD
   images that a configured VOC set already holds (``drop_duplicates``) are removed;
3. classes: an image stays when ``any`` / ``all`` of ``classes`` cover at least ``min_pixels``
   pixels in it (per class or one number for all);
4. caps: at most ``max_images[set]`` images per set, a seeded random subset.

The chosen ids go to ``source_manifest.json`` in the run directory (``Selection.manifest`` reads
such a file back to train on exactly the same images), and a summary (images per set and
filter, pixels per class) is logged. A selection that leaves no image is an error naming the
filter that removed the last ones. Label statistics of VOC / SBD are cached in
``cache_dir/stats`` (keyed by file size and modification time), COCO keeps its own mask cache.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from torch.utils.data import Dataset

from uss_slam.core.classes import CLASS_NAMES, NUM_CLASSES
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import write_bytes_atomic
from uss_slam.core.progress import progress_bar
from uss_slam.datasets.base import (
    LabelStats,
    OnError,
    SegmentationDataset,
    SegmentationSample,
    Transform,
    check_on_error,
    finish_sample,
    handle_bad_input,
    report_skipped,
)
from uss_slam.datasets.transforms import eval_transform

log = logging.getLogger(__name__)

MANIFEST_NAME = "source_manifest.json"
MANIFEST_FORMAT = "uss-slam source manifest 1"
STATS_VERSION = 1


class SelectionError(UssSlamError):
    """The selection settings are invalid or leave no image."""


@dataclass
class Selection:
    """Which images of the source sets to train on (see the module docstring).

    Args:
        classes: project classes an image must show (empty: no class filter).
        require: ``any`` (at least one of ``classes``) or ``all`` of them.
        min_pixels: pixels a class must cover to count as present: one number, or a mapping
            class -> pixels (classes not named use 1).
        max_images: set name -> cap (``null`` = no cap), applied after the filters as a seeded
            random subset.
        seed: seed of the capped subsets.
        exclude_voc_val: drop SBD images whose id is in VOC 2012 ``val`` (read from
            ``voc_val_list``, or ``ImageSets/Segmentation/val.txt`` of the configured VOC set).
        voc_val_list: the VOC ``val.txt`` to use when no VOC set is configured.
        drop_duplicates: drop SBD images whose id a configured VOC set holds (VOC's label wins).
        manifest: a ``source_manifest.json`` of an earlier run: train on exactly its ids (the
            class filter and caps are not applied again; bad input still is).
    """

    classes: Sequence[str] = ("person", "chair", "monitor")
    require: Literal["any", "all"] = "any"
    min_pixels: int | Mapping[str, int] = 1
    max_images: Mapping[str, int | None] = field(default_factory=dict)
    seed: int = 0
    exclude_voc_val: bool = True
    voc_val_list: str | None = None
    drop_duplicates: bool = True
    manifest: str | None = None

    def __post_init__(self) -> None:
        self.classes = [str(c) for c in (self.classes or [])]
        for name in self.classes:
            if name not in CLASS_NAMES[1:]:
                raise SelectionError(
                    f"selection.classes: {name!r} is not a project class "
                    f"(one of {', '.join(CLASS_NAMES[1:])})"
                )
        if self.require not in ("any", "all"):
            raise SelectionError(f"selection.require must be 'any' or 'all', got {self.require!r}")
        if isinstance(self.min_pixels, Mapping):
            pixels = {str(k): int(v) for k, v in self.min_pixels.items()}
            for name in pixels:
                if name not in CLASS_NAMES[1:]:
                    raise SelectionError(f"selection.min_pixels: {name!r} is not a project class")
            self.min_pixels = pixels
        else:
            self.min_pixels = int(self.min_pixels)
        thresholds = list(self.thresholds().values())
        if any(v < 0 for v in thresholds):
            raise SelectionError("selection.min_pixels must not be negative")
        self.max_images = {
            str(k): (None if v is None else int(v)) for k, v in (self.max_images or {}).items()
        }
        if any(v is not None and v < 0 for v in self.max_images.values()):
            raise SelectionError("selection.max_images must not be negative")

    def thresholds(self) -> dict[str, int]:
        """Pixels each of ``classes`` must cover."""
        if isinstance(self.min_pixels, Mapping):
            return {c: int(self.min_pixels.get(c, 1)) for c in self.classes}
        return {c: int(self.min_pixels) for c in self.classes}

    def passes(self, counts: np.ndarray) -> bool:
        """Whether an image with ``counts`` pixels per class passes the class filter."""
        if not self.classes:
            return True
        hits = [counts[CLASS_NAMES.index(c)] >= max(t, 1) for c, t in self.thresholds().items()]
        return all(hits) if self.require == "all" else any(hits)

    def candidate(self, present: frozenset[int]) -> bool:
        """The class filter on the classes annotated in an image (a cheap necessary condition)."""
        if not self.classes:
            return True
        hits = [CLASS_NAMES.index(c) in present for c in self.classes]
        return all(hits) if self.require == "all" else any(hits)

    def describe(self) -> str:
        if not self.classes:
            return "no class filter"
        thresholds = self.thresholds()
        pixels = (
            f"min_pixels {next(iter(thresholds.values()))}"
            if len(set(thresholds.values())) == 1
            else f"min_pixels {thresholds}"
        )
        return f"require {self.require} of {', '.join(self.classes)} ({pixels})"


@dataclass
class SetSummary:
    """What happened to one source set: images removed per stage, pixels per class.

    ``pixels[c]`` / ``images_with[c]``: pixels of class ``c`` in the selected images and the
    number of selected images that show it. ``emptied_by``: the stage that removed the set's
    last image (``None`` while images remain).
    """

    listed: int = 0
    bad_input: int = 0
    overlap: int = 0
    manifest: int = 0
    classes: int = 0
    cap: int = 0
    selected: int = 0
    pixels: list[int] = field(default_factory=lambda: [0] * NUM_CLASSES)
    images_with: list[int] = field(default_factory=lambda: [0] * NUM_CLASSES)
    emptied_by: str | None = None

    def remove(self, stage: str, before: int, after: int) -> None:
        """Count ``before - after`` images removed by ``stage`` (a :data:`STAGES` key)."""
        setattr(self, stage, getattr(self, stage) + before - after)
        if before and not after and self.emptied_by is None:
            self.emptied_by = stage

    def keep(self, stage: str, before: list[int], after: list[int]) -> list[int]:
        """``after``, counting the images of ``before`` that ``stage`` removed."""
        self.remove(stage, len(before), len(after))
        return after


STAGES: dict[str, str] = {
    "bad_input": "bad input (on_error=skip)",
    "overlap": "the overlap rule (SBD vs VOC)",
    "manifest": "the manifest",
    "classes": "the class filter",
    "cap": "the max_images cap",
}


class StatsCache:
    """Per-label class pixel counts of one set, keyed by label path, size and mtime."""

    def __init__(self, cache_dir: str | Path | None, dataset: SegmentationDataset) -> None:
        self.path: Path | None = None
        self.rows: dict[str, tuple[int, int, np.ndarray, int, int]] = {}
        self.dirty = False
        if cache_dir is None:
            return
        key = hashlib.sha1(
            f"{STATS_VERSION} {type(dataset).__qualname__}".encode() + dataset.lut.tobytes()
        )
        first = dataset.items[0].label if dataset.items else None
        key.update(str(Path(first).resolve().parent if first else "").encode())
        self.path = (
            Path(cache_dir) / "stats" / f"{type(dataset).__name__}-{key.hexdigest()[:12]}.npz"
        )
        try:
            with np.load(self.path) as data:
                columns = [data[k] for k in ("paths", "sizes", "mtimes", "counts", "hw")]
            for path, size, mtime, counts, hw in zip(*columns, strict=True):
                self.rows[str(path)] = (int(size), int(mtime), counts, int(hw[0]), int(hw[1]))
        except (OSError, KeyError, ValueError):
            self.rows = {}

    @staticmethod
    def _signature(path: Path) -> tuple[int, int]:
        stat = path.stat()
        return stat.st_size, stat.st_mtime_ns

    def get(self, path: Path) -> LabelStats | None:
        row = self.rows.get(str(path))
        if row is None or self.path is None:
            return None
        try:
            if self._signature(path) != row[:2]:
                return None
        except OSError:
            return None
        return LabelStats(counts=row[2].astype(np.int64), height=row[3], width=row[4])

    def put(self, path: Path, stats: LabelStats) -> None:
        if self.path is None:
            return
        size, mtime = self._signature(path)
        self.rows[str(path)] = (size, mtime, stats.counts, stats.height, stats.width)
        self.dirty = True

    def save(self) -> None:
        if self.path is None or not self.dirty:
            return
        paths = sorted(self.rows)
        rows = [self.rows[p] for p in paths]
        buffer = io.BytesIO()
        np.savez(
            buffer,
            paths=np.array(paths, dtype=str),
            sizes=np.array([r[0] for r in rows], dtype=np.int64),
            mtimes=np.array([r[1] for r in rows], dtype=np.int64),
            counts=np.array([r[2] for r in rows], dtype=np.int64).reshape(-1, NUM_CLASSES),
            hw=np.array([(r[3], r[4]) for r in rows], dtype=np.int64).reshape(-1, 2),
        )
        write_bytes_atomic(self.path, buffer.getvalue())
        self.dirty = False


def read_voc_val_ids(path: Path) -> set[str]:
    from uss_slam.datasets.voc import read_id_list

    return {name for _, name in read_id_list(path)}


class SelectedSources(Dataset):
    """The labelled source dataset: selected images of one or more sets, concatenated.

    Args:
        transform: joint v2 transform applied to every source sample (the sets' own transforms
            are not used); default: normalisation only.
        selection: the filter (:class:`Selection`); default: ``Selection()``.
        on_error: what to do with an item whose files turn out bad while selecting: ``raise``
            a :class:`~uss_slam.core.errors.DataFormatError`, or ``skip`` it (counted).
        cache_dir: where label statistics are cached (``None``: not cached).
        progress: progress bars while reading labels (``None``: only on a terminal).
        **sets: the source sets by name (``voc=VOCSegmentation(...)``, ``sbd=...``, ``coco=...``),
            in the order they are concatenated.

    Samples as the sets' (``image (3, H, W)`` float32, ``label (H, W)`` int64), with
    ``name = "<set>/<id>"``.
    """

    def __init__(
        self,
        transform: Transform | None = None,
        selection: Selection | None = None,
        on_error: OnError = "raise",
        cache_dir: str | Path | None = None,
        progress: bool | None = None,
        **sets: SegmentationDataset,
    ) -> None:
        if not sets:
            raise SelectionError("no source set configured (e.g. data/source=[voc,sbd,coco])")
        for name, dataset in sets.items():
            if (
                not isinstance(dataset, SegmentationDataset)
                or not dataset.labelled
                and len(dataset)
            ):
                raise SelectionError(f"source set {name!r} is not a labelled segmentation dataset")
        self.sets: dict[str, SegmentationDataset] = dict(sets)
        self.transform = transform if transform is not None else eval_transform()
        self.selection = selection if selection is not None else Selection()
        self.on_error = check_on_error(on_error)
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        self.progress = progress
        unknown = [
            k for k, v in self.selection.max_images.items() if v is not None and k not in sets
        ]
        if unknown:
            raise SelectionError(
                f"selection.max_images names {unknown}, which are not configured source sets "
                f"({', '.join(sets)})"
            )
        self.summary: dict[str, SetSummary] = {}
        self.skipped: dict[str, list[DataFormatError]] = {}
        self.chosen: dict[str, list[int]] = self._select()
        self.index: list[tuple[str, int]] = [
            (name, i) for name, indices in self.chosen.items() for i in indices
        ]
        self.log_summary()

    # ----------------------------------------------------------------------------- selection

    def _quiet(self, n: int) -> bool | None:
        if self.progress is None:
            return None if n > 50 else True
        return not self.progress

    def _voc_val_ids(self) -> set[str] | None:
        from uss_slam.datasets.voc import VOCSegmentation

        if self.selection.voc_val_list:
            return read_voc_val_ids(Path(self.selection.voc_val_list))
        for dataset in self.sets.values():
            if isinstance(dataset, VOCSegmentation):
                return read_voc_val_ids(dataset.root / "ImageSets" / "Segmentation" / "val.txt")
        return None

    def _overlap(self, name: str, dataset: SegmentationDataset, indices: list[int]) -> list[int]:
        from uss_slam.datasets.sbd import SBDSegmentation
        from uss_slam.datasets.voc import VOCSegmentation

        if not isinstance(dataset, SBDSegmentation):
            return indices
        drop: set[str] = set()
        if self.selection.exclude_voc_val:
            val = self._voc_val_ids()
            if val is None:
                raise SelectionError(
                    f"selection.exclude_voc_val: set {name!r} is SBD but no VOC set is "
                    "configured; give selection.voc_val_list (VOC2012/ImageSets/Segmentation/"
                    "val.txt) or set exclude_voc_val=false"
                )
            drop |= val
        if self.selection.drop_duplicates:
            for other in self.sets.values():
                if isinstance(other, VOCSegmentation):
                    drop |= {item.name for item in other.items}
        return [i for i in indices if dataset.items[i].name not in drop]

    def _manifest_ids(self) -> dict[str, list[str]] | None:
        if not self.selection.manifest:
            return None
        path = Path(self.selection.manifest)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise DataFormatError(path, "manifest not found") from None
        except json.JSONDecodeError as error:
            raise DataFormatError(path, f"not valid JSON: {error.msg}", error.lineno) from None
        if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
            raise DataFormatError(
                path, f"not a source manifest (expected format {MANIFEST_FORMAT!r})"
            )
        sets = data.get("sets", {})
        missing = [name for name in self.sets if name not in sets]
        extra = [name for name in sets if name not in self.sets]
        if missing or extra:
            raise DataFormatError(
                path,
                f"the manifest's sets {sorted(sets)} differ from the configured sets "
                f"{sorted(self.sets)}",
            )
        return {name: [str(i) for i in sets[name]["ids"]] for name in self.sets}

    def _stats(
        self, name: str, dataset: SegmentationDataset, indices: list[int]
    ) -> tuple[dict[int, LabelStats], list[DataFormatError]]:
        """Label statistics of ``indices`` and the bad inputs found while reading them."""
        bad: list[DataFormatError] = []
        prepare = getattr(dataset, "prepare_labels", None)
        if prepare is not None:
            prepare(indices)
        cache = StatsCache(
            self.cache_dir if getattr(dataset, "cache_label_stats", True) else None, dataset
        )
        stats: dict[int, LabelStats] = {}
        try:
            for i in progress_bar(
                indices, desc=f"labels of {name}", disable=self._quiet(len(indices))
            ):
                item = dataset.items[i]
                try:
                    found = cache.get(item.label) if item.label is not None else None
                    if found is None:
                        found = dataset.label_stats(i)
                        if item.label is not None:
                            cache.put(item.label, found)
                    dataset.check_image(i, found.height, found.width)
                except DataFormatError as error:
                    handle_bad_input(error, self.on_error, bad)
                    continue
                stats[i] = found
        finally:
            cache.save()  # keep what was read even if a bad file stops the run
        return stats, bad

    def _select(self) -> dict[str, list[int]]:
        selection = self.selection
        manifest = self._manifest_ids()
        chosen: dict[str, list[int]] = {}
        for set_number, (name, dataset) in enumerate(self.sets.items()):
            summary = SetSummary(listed=len(dataset) + len(dataset.skipped))
            summary.remove("bad_input", summary.listed, len(dataset))
            self.summary[name] = summary
            skipped = list(dataset.skipped)
            indices = list(range(len(dataset)))

            if manifest is not None:
                by_name = {item.name: i for i, item in enumerate(dataset.items)}
                unknown = [n for n in manifest[name] if n not in by_name]
                if unknown:
                    raise DataFormatError(
                        self.selection.manifest,  # type: ignore[arg-type]
                        f"set {name!r}: {len(unknown)} id(s) are not in the configured set, "
                        f"e.g. {unknown[:5]}",
                    )
                indices = summary.keep(
                    "manifest", indices, sorted(by_name[n] for n in manifest[name])
                )
            else:
                indices = summary.keep("overlap", indices, self._overlap(name, dataset, indices))
                present = getattr(dataset, "present_classes", None)
                if present is not None:  # cheap pre-filter from the annotations (COCO)
                    indices = summary.keep(
                        "classes", indices, [i for i in indices if selection.candidate(present(i))]
                    )
            stats, bad = self._stats(name, dataset, indices)
            skipped += bad
            indices = summary.keep("bad_input", indices, [i for i in indices if i in stats])
            if manifest is None:
                indices = summary.keep(
                    "classes", indices, [i for i in indices if selection.passes(stats[i].counts)]
                )
                cap = selection.max_images.get(name)
                if cap is not None and len(indices) > cap:
                    rng = np.random.default_rng([selection.seed, set_number])
                    indices = summary.keep(
                        "cap", indices, sorted(rng.choice(indices, cap, replace=False).tolist())
                    )
            summary.selected = len(indices)
            for i in indices:
                counts = stats[i].counts
                summary.pixels = [int(a + b) for a, b in zip(summary.pixels, counts, strict=True)]
                summary.images_with = [
                    int(a + (b > 0)) for a, b in zip(summary.images_with, counts, strict=True)
                ]
            chosen[name] = indices
            self.skipped[name] = skipped
            report_skipped(f"source set {name}", bad)
        if not any(chosen.values()):
            raise SelectionError(self._empty_message())
        for name, indices in chosen.items():
            if not indices:
                log.warning("source set %s contributes no image: %s", name, self._set_line(name))
        return chosen

    def _stage(self, key: str) -> str:
        label = STAGES[key]
        if key == "classes":
            label += f" ({self.selection.describe()})"
        elif key == "manifest":
            label += f" {self.selection.manifest}"
        return label

    def _set_line(self, name: str) -> str:
        s = self.summary[name]
        parts = [f"{s.listed} listed"]
        parts += [
            f"{getattr(s, key)} removed by {STAGES[key]}" for key in STAGES if getattr(s, key)
        ]
        return ", ".join(parts) + f", {s.selected} left"

    def _empty_message(self) -> str:
        culprits = {s.emptied_by for s in self.summary.values()}
        if culprits == {None}:
            lead = "the source sets list no images"
        elif len(culprits) == 1:
            lead = f"{self._stage(culprits.pop())} removed the last ones"  # type: ignore[arg-type]
        else:
            lead = "each set was emptied by another filter"
        sets = "; ".join(
            f"{name}: {self._set_line(name)}"
            + (f" (emptied by {STAGES[s.emptied_by]})" if s.emptied_by else "")
            for name, s in self.summary.items()
        )
        return f"the source selection left no images: {lead} ({sets})"

    # ----------------------------------------------------------------------------- results

    def __len__(self) -> int:
        return len(self.index)

    @property
    def labelled(self) -> bool:
        return True

    def __getitem__(self, index: int) -> SegmentationSample:
        name, i = self.index[index]
        sample = self.sets[name].load(i)
        sample["name"] = f"{name}/{sample['name']}"
        return finish_sample(self.transform(sample))

    def summary_table(self) -> str:
        """The per-set summary as an aligned text table."""
        classes = CLASS_NAMES[1:]
        header = ["set", "listed", "bad", "overlap", "manifest", "classes", "cap", "selected"]
        header += [f"{c} img/px" for c in classes]
        rows = [header]
        total = SetSummary()
        for name, s in self.summary.items():
            row = [name, s.listed, s.bad_input, s.overlap, s.manifest, s.classes, s.cap]
            row.append(s.selected)
            row += [f"{s.images_with[k]}/{s.pixels[k]}" for k in range(1, NUM_CLASSES)]
            rows.append([str(v) for v in row])
            for key in ("listed", *STAGES, "selected"):
                setattr(total, key, getattr(total, key) + getattr(s, key))
            total.pixels = [a + b for a, b in zip(total.pixels, s.pixels, strict=True)]
            total.images_with = [
                a + b for a, b in zip(total.images_with, s.images_with, strict=True)
            ]
        if len(self.summary) > 1:
            row = ["total", total.listed, *(getattr(total, key) for key in STAGES)]
            row.append(total.selected)
            row += [f"{total.images_with[k]}/{total.pixels[k]}" for k in range(1, NUM_CLASSES)]
            rows.append([str(v) for v in row])
        widths = [max(len(r[k]) for r in rows) for k in range(len(header))]
        lines = []
        for row in rows:
            cells = [row[0].ljust(widths[0])] + [
                v.rjust(w) for v, w in zip(row[1:], widths[1:], strict=True)
            ]
            lines.append("  ".join(cells))
        return "\n".join(lines)

    def log_summary(self) -> None:
        log.info("source selection (%s):\n%s", self.selection.describe(), self.summary_table())

    def manifest(self) -> dict[str, Any]:
        """The manifest: settings, the chosen ids per set, the summary and the skipped inputs."""
        sets = {}
        for name, indices in self.chosen.items():
            dataset = self.sets[name]
            sets[name] = {
                "type": type(dataset).__name__,
                "root": str(
                    getattr(dataset, "root", "") or getattr(dataset, "annotation_file", "")
                ),
                "split": getattr(dataset, "split", None),
                "ids": [dataset.items[i].name for i in indices],
            }
        return {
            "format": MANIFEST_FORMAT,
            "selection": asdict(self.selection),
            "sets": sets,
            "summary": {name: asdict(s) for name, s in self.summary.items()},
            "class_names": list(CLASS_NAMES),
            "skipped": {name: [str(e) for e in errors] for name, errors in self.skipped.items()},
        }

    def write_manifest(self, directory: str | Path) -> Path:
        """Write ``source_manifest.json`` into ``directory`` (the run directory); returns it."""
        path = Path(directory) / MANIFEST_NAME
        write_bytes_atomic(path, (json.dumps(self.manifest(), indent=1) + "\n").encode())
        log.info("source manifest: %s (%d images)", path, len(self))
        return path

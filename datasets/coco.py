"""COCO-format instance annotations as semantic labels (COCO 2017 and annotation-tool exports).

Layout of COCO 2017::

    <root>/annotations/instances_<split>2017.json
    <root>/<split>2017/<file_name>

(``annotations`` / ``images`` name other places, e.g. a CVAT or labelme COCO export; a
``file_name`` may contain sub-folders.) The JSON needs ``images`` (``id``, ``file_name``,
``width``, ``height``), ``annotations`` (``image_id``, ``category_id``, ``segmentation``,
optional ``iscrowd`` and ``id``) and ``categories`` (``id``, ``name``).

Categories map to project classes **by name** (``categories``: project class -> accepted
names, compared case-insensitively with punctuation and spaces removed, so ``tv/monitor``,
``TV Monitor`` and ``tvmonitor`` are one name); every other category is background.

Rasterisation (pycocotools): polygons, compressed and uncompressed RLE. Crowd annotations of
mapped categories become ``255`` (ignore); instances are painted over crowd regions in order of
decreasing mask area (ties: increasing annotation id), so where instances overlap the **smaller
one wins** (a person in front of a monitor keeps its pixels). Masks are cached as PNGs of
project ids under ``cache_dir`` together with the per-class pixel counts; a cache whose
annotation file hash (SHA-256) or category mapping differs is wiped and rebuilt.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
import shutil
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pycocotools import mask as mask_utils

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX, NUM_CLASSES
from uss_slam.core.errors import DataFormatError
from uss_slam.core.files import file_sha256, write_bytes_atomic
from uss_slam.core.images import read_image
from uss_slam.core.paths import read_text
from uss_slam.core.progress import progress_bar
from uss_slam.datasets.base import (
    ImageItem,
    LabelStats,
    OnError,
    SegmentationDataset,
    Transform,
    check_on_error,
    handle_bad_input,
    inspect_image,
    report_skipped,
)

log = logging.getLogger(__name__)

DEFAULT_CATEGORIES: dict[str, list[str]] = {
    "person": ["person"],
    "chair": ["chair"],
    "monitor": ["tv", "tv/monitor", "tvmonitor", "monitor"],
}
"""Project class -> COCO category names: COCO's ``person`` (id 1), ``chair`` (62), ``tv`` (72),
and the names annotation tools and VOC use for monitors."""

CACHE_VERSION = 1
"""Bump when the rasterisation rule changes: older caches are then rebuilt."""


def normalize_name(name: str) -> str:
    """Category names compare without case, spaces or punctuation (``tv/monitor`` = ``TV Monitor``)."""
    return re.sub(r"[^0-9a-z]+", "", str(name).lower())


def category_table(categories: Mapping[str, Sequence[str]]) -> dict[str, int]:
    """Normalised accepted name -> project class id; checks the project class names."""
    table: dict[str, int] = {}
    for class_name, names in categories.items():
        if class_name not in CLASS_NAMES or class_name == CLASS_NAMES[0]:
            raise ValueError(
                f"categories: {class_name!r} is not a project class "
                f"(one of {', '.join(CLASS_NAMES[1:])})"
            )
        accepted = [names] if isinstance(names, str) else list(names)
        for name in accepted:
            key = normalize_name(name)
            other = table.get(key)
            if other is not None and other != CLASS_NAMES.index(class_name):
                raise ValueError(
                    f"categories: name {name!r} is listed for both {CLASS_NAMES[other]!r} "
                    f"and {class_name!r}"
                )
            table[key] = CLASS_NAMES.index(class_name)
    return table


@dataclass
class CocoImage:
    """One image of the annotation file, with the annotations of mapped categories."""

    id: int
    file_name: str
    width: int
    height: int
    present: frozenset[int] = frozenset()  # project classes of non-crowd mapped instances
    annotations: list[dict[str, Any]] = field(default_factory=list)  # mapped: crowd + instances


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _hashable(value: Any) -> Any:
    """``value`` if it can be a set member (JSON ids may be lists or objects by mistake)."""
    return value if isinstance(value, (int, float, str, type(None))) else repr(value)


def _check_segmentation(segmentation: Any, height: int, width: int) -> str | None:
    """Why ``segmentation`` is no valid polygon list / RLE for a ``height × width`` image."""
    if isinstance(segmentation, list):
        if not segmentation:
            return "empty polygon list"
        for polygon in segmentation:
            if not isinstance(polygon, list) or not all(_is_number(v) for v in polygon):
                return "polygons must be lists of numbers [x1, y1, x2, y2, ...]"
            if len(polygon) < 6 or len(polygon) % 2:
                return f"a polygon needs an even number >= 6 of coordinates, got {len(polygon)}"
        return None
    if isinstance(segmentation, dict):
        size, counts = segmentation.get("size"), segmentation.get("counts")
        if not (isinstance(size, list) and len(size) == 2 and all(_is_int(v) for v in size)):
            return "RLE needs 'size': [height, width]"
        if size != [height, width]:
            return f"RLE size {size} differs from the image's [height, width] [{height}, {width}]"
        if isinstance(counts, list):
            if not all(_is_int(v) and v >= 0 for v in counts) or sum(counts) != height * width:
                return f"uncompressed RLE counts must be non-negative and sum to {height * width}"
            return None
        if isinstance(counts, str):
            return None
        return "RLE needs 'counts' (a string, or a list of run lengths)"
    return "expected a polygon list or an RLE dict"


def annotation_mask(segmentation: Any, height: int, width: int) -> np.ndarray:
    """``(H, W)`` bool mask of a COCO segmentation (polygons, RLE, uncompressed RLE)."""
    if isinstance(segmentation, list):
        rle = mask_utils.merge(mask_utils.frPyObjects(segmentation, height, width))
    elif isinstance(segmentation["counts"], list):
        rle = mask_utils.frPyObjects(segmentation, height, width)
    else:
        rle = {"size": segmentation["size"], "counts": segmentation["counts"].encode("ascii")}
    return mask_utils.decode(rle).astype(bool)


def rasterize(image: CocoImage) -> np.ndarray:
    """``(H, W)`` uint8 project ids of one image (see the module docstring for the rule)."""
    label = np.zeros((image.height, image.width), dtype=np.uint8)
    instances = []
    for annotation in image.annotations:
        mask = annotation_mask(annotation["segmentation"], image.height, image.width)
        if annotation["iscrowd"]:
            label[mask] = IGNORE_INDEX
        else:
            instances.append((-int(mask.sum()), annotation["id"], mask, annotation["class"]))
    for _, _, mask, class_id in sorted(instances, key=lambda t: (t[0], t[1])):
        label[mask] = class_id
    return label


def _error_record(error: DataFormatError) -> dict[str, Any]:
    return {"path": error.path, "line": error.line, "message": error.detail}


def _error_from(record: Mapping[str, Any]) -> DataFormatError:
    return DataFormatError(record["path"], record["message"], record["line"])


class COCOSegmentation(SegmentationDataset):
    """COCO-format instance annotations rasterised to project-class labels.

    Args:
        root: COCO folder holding ``annotations/`` and ``<split><year>/`` (optional when
            ``annotations`` and ``images`` are given).
        split: ``train`` or ``val`` (file ``instances_<split><year>.json``).
        year: the release year in the COCO file names.
        annotations: the instances JSON (default ``<root>/annotations/instances_<split><year>.json``).
        images: folder that ``file_name`` is relative to (default ``<root>/<split><year>``).
        categories: project class -> accepted category names (default
            :data:`DEFAULT_CATEGORIES`); categories that match none are background.
        cache_dir: where rasterised masks are kept (``<cache_dir>/coco/<json name>-<path hash>/``);
            ``None`` rasterises in memory on every read.
        transform: joint v2 transform (see :mod:`uss_slam.datasets.transforms`).
        on_error: ``raise``: a bad entry (image entry without id / size, annotation of an unknown
            image or category, malformed segmentation, missing image file) is an error naming
            the JSON file and the entry; ``skip``: the affected image is left out and recorded in
            ``skipped``. Invalid JSON and missing top-level keys always raise.
        progress: show a progress bar while rasterising (``None``: only on a terminal).

    Samples: ``image (3, H, W)`` float32, ``label (H, W)`` int64, ``name`` = the image id.
    Only images listed in ``images`` are items; images without mapped annotations are all
    background.
    """

    cache_label_stats = False  # one JSON for all items; the mask cache keeps the counts

    def __init__(
        self,
        root: str | Path | None = None,
        split: str = "train",
        year: int | str = 2017,
        annotations: str | Path | None = None,
        images: str | Path | None = None,
        categories: Mapping[str, Sequence[str]] | None = None,
        cache_dir: str | Path | None = None,
        transform: Transform | None = None,
        on_error: OnError = "raise",
        progress: bool | None = None,
    ) -> None:
        self.on_error = check_on_error(on_error)
        if root is None and (annotations is None or images is None):
            raise ValueError("COCOSegmentation needs root, or both annotations and images")
        if root is not None and not Path(root).is_dir():
            raise DataFormatError(root, "COCO root not found")
        self.annotation_file = Path(
            annotations
            if annotations is not None
            else Path(root) / "annotations" / f"instances_{split}{year}.json"  # type: ignore[arg-type]
        )
        self.image_dir = Path(images if images is not None else Path(root) / f"{split}{year}")  # type: ignore[arg-type]
        if not self.annotation_file.is_file():
            raise DataFormatError(self.annotation_file, "COCO annotation file not found")
        if not self.image_dir.is_dir():
            raise DataFormatError(self.image_dir, "COCO image folder not found")
        self.categories = {
            str(k): [str(v)] if isinstance(v, str) else [str(n) for n in v]
            for k, v in (categories if categories is not None else DEFAULT_CATEGORIES).items()
        }
        self.table = category_table(self.categories)
        self.split = split if annotations is None else None  # recorded in the manifest
        self.progress = progress
        self.sha256 = file_sha256(self.annotation_file)
        self.cache = self._cache_folder(cache_dir)
        self._images: list[CocoImage] | None = None  # parsed annotations (None: not parsed)
        self._counts: dict[int, list[int]] = {}  # image id -> pixels per class (cached masks)
        self._failed: dict[int, DataFormatError] = {}  # image id -> rasterisation error

        index = self._load_index()
        if index is None:
            images_, skipped = self._parse()
            index = self._index(images_, skipped)
            self._images = images_
            self._write_index(index)
        else:
            self._counts = {int(k): v for k, v in index.get("counts", {}).items()}
        self.entries: list[dict[str, Any]] = index["images"]
        self._skipped_records: list[dict[str, Any]] = index["skipped"]
        skipped = [_error_from(record) for record in self._skipped_records]
        if skipped and self.on_error == "raise":  # a cache built with on_error=skip
            raise skipped[0]

        items: list[ImageItem] = []
        self.meta: list[dict[str, Any]] = []
        for entry in self.entries:
            path = self.image_dir / entry["file_name"]
            if not path.is_file():
                error = DataFormatError(
                    self.annotation_file,
                    f"image {entry['id']}: file {path} not found (file_name is relative to "
                    f"{self.image_dir})",
                )
                handle_bad_input(error, self.on_error, skipped)
                continue
            items.append(ImageItem(image=path, label=self.annotation_file, name=str(entry["id"])))
            self.meta.append(entry)
        report_skipped(f"COCO {self.annotation_file}", skipped)
        super().__init__(items, lut=None, transform=transform, skipped=skipped)

    # ----------------------------------------------------------------------------- parsing

    def _bad(self, message: str, skipped: list[DataFormatError]) -> None:
        handle_bad_input(DataFormatError(self.annotation_file, message), self.on_error, skipped)

    def _parse(self) -> tuple[list[CocoImage], list[DataFormatError]]:
        """Read and check the JSON; returns the images (mapped annotations attached)."""
        path = self.annotation_file
        log.info("reading COCO annotations %s", path)
        text = read_text(path, "expected a COCO annotation JSON file")  # a bad byte: its line
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise DataFormatError(path, f"not valid JSON: {error.msg}", error.lineno) from None
        if not isinstance(data, dict):
            raise DataFormatError(
                path, "expected a JSON object with images, annotations, categories"
            )
        missing = [key for key in ("images", "annotations", "categories") if key not in data]
        if missing:
            raise DataFormatError(
                path, f"missing required key(s) {missing} (a COCO instances file)"
            )
        for key in ("images", "annotations", "categories"):
            if not isinstance(data[key], list):
                raise DataFormatError(path, f"{key!r} must be a list")

        class_of: dict[int, int] = {}
        for k, category in enumerate(data["categories"]):
            valid = isinstance(category, dict) and _is_int(category.get("id"))
            if not (valid and isinstance(category.get("name"), str)):
                raise DataFormatError(path, f"categories[{k}]: needs an integer 'id' and a 'name'")
            if category["id"] in class_of:
                raise DataFormatError(path, f"categories[{k}]: duplicate id {category['id']}")
            class_of[category["id"]] = self.table.get(normalize_name(category["name"]), 0)
        found = {CLASS_NAMES[c] for c in class_of.values() if c}
        if not found:
            names = sorted({str(c["name"]) for c in data["categories"]})
            raise DataFormatError(
                path,
                f"no category matches the configured classes {self.categories}; the file has "
                f"{names[:20]}",
            )
        if found != set(self.categories):
            log.info("%s: no category for %s", path.name, sorted(set(self.categories) - found))

        skipped: list[DataFormatError] = []
        images: dict[int, CocoImage] = {}
        rejected: set[Any] = set()  # ids of bad image entries (reported once, not per annotation)
        bad_images: set[Any] = set()  # images left out (an entry or annotation of theirs is bad)
        for k, entry in enumerate(data["images"]):
            if not isinstance(entry, dict):
                self._bad(f"images[{k}]: expected an object", skipped)
                continue
            lacking = [key for key in ("id", "file_name", "width", "height") if key not in entry]
            if lacking:
                self._bad(f"images[{k}]: missing required key(s) {lacking}", skipped)
                rejected.add(_hashable(entry.get("id")))
                continue
            image_id, width, height = entry["id"], entry["width"], entry["height"]
            sizes_ok = _is_int(width) and _is_int(height) and width > 0 and height > 0
            if not (_is_int(image_id) and sizes_ok and isinstance(entry["file_name"], str)):
                self._bad(
                    f"images[{k}]: id, width, height must be integers (> 0), file_name a string",
                    skipped,
                )
                rejected.add(_hashable(image_id))
                continue
            if image_id in images:
                self._bad(f"images[{k}]: duplicate image id {image_id}", skipped)
                bad_images.add(image_id)  # which entry do its annotations belong to?
                continue
            images[image_id] = CocoImage(image_id, entry["file_name"], width, height)

        for k, annotation in enumerate(data["annotations"]):
            where = f"annotations[{k}]"
            if isinstance(annotation, dict) and "id" in annotation:
                where += f" (id {annotation['id']})"
            if not isinstance(annotation, dict):
                self._bad(f"{where}: expected an object", skipped)
                continue
            lacking = [
                key for key in ("image_id", "category_id", "segmentation") if key not in annotation
            ]
            if lacking:
                self._bad(f"{where}: missing required key(s) {lacking}", skipped)
                bad_images.add(_hashable(annotation.get("image_id")))
                continue
            image = images.get(_hashable(annotation["image_id"]))
            if image is None and _hashable(annotation["image_id"]) in rejected:
                continue  # its image entry is bad and already reported
            if image is None:
                self._bad(f"{where}: image_id {annotation['image_id']!r} is not in images", skipped)
                continue
            if _hashable(annotation["category_id"]) not in class_of:
                self._bad(
                    f"{where}: category_id {annotation['category_id']!r} is not in categories "
                    f"(image {image.id}, {image.file_name})",
                    skipped,
                )
                bad_images.add(image.id)
                continue
            class_id = class_of[annotation["category_id"]]
            if not class_id:
                continue  # background: nothing to paint
            reason = _check_segmentation(annotation["segmentation"], image.height, image.width)
            if reason:
                self._bad(f"{where}: {reason} (image {image.id}, {image.file_name})", skipped)
                bad_images.add(image.id)
                continue
            crowd = bool(annotation.get("iscrowd", 0))
            image.annotations.append(
                {
                    "id": annotation.get("id", k) if _is_int(annotation.get("id", k)) else k,
                    "class": class_id,
                    "iscrowd": crowd,
                    "segmentation": annotation["segmentation"],
                }
            )
            if not crowd:
                image.present = image.present | {class_id}
        kept = [image for image_id, image in images.items() if image_id not in bad_images]
        return kept, skipped

    # ----------------------------------------------------------------------------- cache

    def _cache_folder(self, cache_dir: str | Path | None) -> Path | None:
        if cache_dir is None:
            return None
        where = hashlib.sha1(str(self.annotation_file.resolve()).encode()).hexdigest()[:8]
        return Path(cache_dir) / "coco" / f"{self.annotation_file.stem}-{where}"

    def _cache_key(self) -> dict[str, Any]:
        return {
            "version": CACHE_VERSION,
            "annotations": str(self.annotation_file.resolve()),
            "sha256": self.sha256,
            "categories": {
                k: sorted(normalize_name(n) for n in v) for k, v in self.categories.items()
            },
        }

    def _load_index(self) -> dict[str, Any] | None:
        """The cached index if it was built from this very file and mapping, else ``None``
        (a stale cache is wiped)."""
        if self.cache is None:
            return None
        index_file = self.cache / "index.json"
        try:
            index = json.loads(index_file.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            index = None
        if index is not None and index.get("key") == self._cache_key():
            log.info("COCO mask cache %s: up to date", self.cache)
            return index
        if self.cache.exists():
            log.warning(
                "COCO mask cache %s was built from another annotation file or mapping: rebuilding",
                self.cache,
            )
            shutil.rmtree(self.cache)
        return None

    def _index(self, images: list[CocoImage], skipped: list[DataFormatError]) -> dict[str, Any]:
        entries = [
            {
                "id": image.id,
                "file_name": image.file_name,
                "width": image.width,
                "height": image.height,
                "present": sorted(image.present),
                "mapped": bool(image.annotations),
            }
            for image in images
        ]
        return {
            "key": self._cache_key(),
            "images": entries,
            "skipped": [_error_record(e) for e in skipped],
            "counts": {},
        }

    def _write_index(self, index: dict[str, Any]) -> None:
        if self.cache is None:
            return
        (self.cache / "masks").mkdir(parents=True, exist_ok=True)
        index = {**index, "counts": {str(k): v for k, v in self._counts.items()}}
        write_bytes_atomic(self.cache / "index.json", json.dumps(index).encode())

    def _mask_file(self, image_id: int) -> Path:
        assert self.cache is not None
        return self.cache / "masks" / f"{image_id}.png"

    def _parsed(self) -> dict[int, CocoImage]:
        if self._images is None:
            self._images, _ = self._parse()
        return {image.id: image for image in self._images}

    # ----------------------------------------------------------------------------- labels

    def present_classes(self, index: int) -> frozenset[int]:
        """Project classes with a non-crowd instance in item ``index`` (from the JSON, cheap)."""
        return frozenset(self.meta[index]["present"])

    def prepare_labels(self, indices: Iterable[int]) -> None:
        """Rasterise the masks of ``indices`` that are not cached yet (with a progress bar)."""
        todo = [
            i
            for i in indices
            if self.meta[i]["mapped"]
            and self.meta[i]["id"] not in self._failed
            and (self.meta[i]["id"] not in self._counts or self.cache is None)
        ]
        if not todo or self.cache is None:
            return
        parsed = self._parsed()
        for i in progress_bar(
            todo, desc=f"COCO masks {self.annotation_file.name}", disable=self._quiet(len(todo))
        ):
            image_id = self.meta[i]["id"]
            try:
                label = rasterize(parsed[image_id])
            except (ValueError, TypeError, KeyError) as error:
                self._failed[image_id] = DataFormatError(
                    self.annotation_file, f"image {image_id}: cannot rasterise ({error})"
                )
                continue
            ok, png = cv2.imencode(".png", label)
            assert ok
            write_bytes_atomic(self._mask_file(image_id), png.tobytes())
            self._counts[image_id] = np.bincount(label.ravel(), minlength=256)[
                :NUM_CLASSES
            ].tolist()
        self._write_index(
            {
                "key": self._cache_key(),
                "images": self.entries,
                "skipped": self._skipped_records,
            }
        )
        self._images = None  # masks are on disk now: free the parsed annotations

    def _quiet(self, n: int) -> bool | None:
        if self.progress is None:
            return None if n > 20 else True
        return not self.progress

    def read_label(self, index: int) -> np.ndarray:
        entry = self.meta[index]
        image_id = entry["id"]
        if image_id in self._failed:
            raise self._failed[image_id]
        if not entry["mapped"]:
            return np.zeros((entry["height"], entry["width"]), dtype=np.uint8)
        if self.cache is not None and self._mask_file(image_id).is_file():
            try:  # a damaged cached mask is made again
                label = read_image(self._mask_file(image_id), cv2.IMREAD_UNCHANGED)
            except DataFormatError:
                label = None
            if label is not None and label.shape == (entry["height"], entry["width"]):
                return label
        try:
            label = rasterize(self._parsed()[image_id])
        except (ValueError, TypeError, KeyError) as error:
            raise DataFormatError(
                self.annotation_file, f"image {image_id}: cannot rasterise ({error})"
            ) from error
        if self.cache is not None:  # read outside selection (e.g. as a validation set): keep it
            write_bytes_atomic(self._mask_file(image_id), cv2.imencode(".png", label)[1].tobytes())
        return label

    def label_stats(self, index: int) -> LabelStats:
        entry = self.meta[index]
        if entry["id"] in self._counts and entry["id"] not in self._failed:
            counts = np.asarray(self._counts[entry["id"]], dtype=np.int64)
            return LabelStats(counts=counts, height=entry["height"], width=entry["width"])
        return super().label_stats(index)

    def check_image(self, index: int, height: int, width: int) -> None:
        entry = self.meta[index]
        image_width, image_height = inspect_image(self.items[index].image)
        if (image_width, image_height) != (entry["width"], entry["height"]):
            raise DataFormatError(
                self.annotation_file,
                f"image {entry['id']} is {entry['width']}×{entry['height']} in the annotations "
                f"but its file {entry['file_name']} is {image_width}×{image_height}",
            )

"""Writers of small data sets in the exact real formats, for the real-data loader tests.

- VOC 2012: ``VOCdevkit/VOC2012/{JPEGImages/*.jpg, SegmentationClass/*.png (palette),
  ImageSets/Segmentation/<split>.txt}``;
- SBD: ``benchmark_RELEASE/dataset/{img/*.jpg, cls/*.mat (struct GTcls with Boundaries,
  Segmentation, CategoriesPresent, as MATLAB writes it), <split>.txt}``;
- COCO: ``annotations/instances_<split>2017.json`` (polygons, compressed RLE, uncompressed RLE,
  crowd) and ``<split>2017/*.jpg``;
- TUM RGB-D: ``rgb.txt`` and ``rgb/*.png`` (no depth).

A :class:`Scene` is a list of objects (VOC class index, boolean mask, crowd flag, how to encode
it in COCO); :func:`paint_voc` paints it with the loaders' overlap rule (crowd first as void,
then instances by decreasing area) so that the same scene written as VOC and as COCO must give
identical project labels.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io
import scipy.sparse
from PIL import Image
from pycocotools import mask as mask_utils

from uss_slam.core.classes import VOC_CLASS_NAMES, voc_palette
from uss_slam.core.tum_io import write_file_list

# COCO 2017 category ids and names of the classes the tests use (the official file's values).
COCO_CATEGORIES = [
    {"id": 1, "name": "person", "supercategory": "person"},
    {"id": 18, "name": "dog", "supercategory": "animal"},
    {"id": 62, "name": "chair", "supercategory": "furniture"},
    {"id": 72, "name": "tv", "supercategory": "electronic"},
]
VOC_TO_COCO_ID = {15: 1, 12: 18, 9: 62, 20: 72}  # person, dog, chair, tvmonitor


@dataclass(frozen=True)
class Obj:
    voc_class: int  # VOC index (15 person, 9 chair, 20 tvmonitor, 12 dog)
    mask: np.ndarray  # (H, W) bool
    crowd: bool = False
    encoding: str = "polygon"  # COCO: polygon (rectangles only) | rle | raw (uncompressed RLE)
    box: tuple[int, int, int, int] | None = None  # x0, y0, x1, y1 of a rectangle


def rect(shape: tuple[int, int], x0: int, y0: int, x1: int, y1: int, voc_class: int, **kw) -> Obj:
    mask = np.zeros(shape, dtype=bool)
    mask[y0:y1, x0:x1] = True
    return Obj(voc_class, mask, box=(x0, y0, x1, y1), **kw)


def ellipse(shape: tuple[int, int], cx: float, cy: float, rx: float, ry: float, voc_class: int,
            **kw) -> Obj:  # fmt: skip
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    mask = ((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1.0
    return Obj(voc_class, mask, encoding=kw.pop("encoding", "rle"), **kw)


Scene = list[Obj]


def paint_voc(shape: tuple[int, int], scene: Scene) -> np.ndarray:
    """VOC indices of a scene: crowd regions void (255), then instances larger-first."""
    label = np.zeros(shape, dtype=np.uint8)
    for obj in scene:
        if obj.crowd:
            label[obj.mask] = 255
    instances = [o for o in scene if not o.crowd]
    order = sorted(range(len(instances)), key=lambda k: (-int(instances[k].mask.sum()), k))
    for k in order:
        label[instances[k].mask] = instances[k].voc_class
    return label


def scene_image(shape: tuple[int, int], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (*shape, 3), dtype=np.uint8)


def save_jpeg(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(path, quality=90)


def save_palette_png(path: Path, label: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    png = Image.fromarray(label, mode="P")
    png.putpalette(voc_palette().tobytes())
    png.save(path)


def write_voc(
    root: Path, labels: Mapping[str, np.ndarray], splits: Mapping[str, Sequence[str]]
) -> Path:
    """A ``VOCdevkit/VOC2012`` tree under ``root``; returns the ``VOC2012`` folder."""
    voc = root / "VOCdevkit" / "VOC2012"
    (voc / "ImageSets" / "Segmentation").mkdir(parents=True, exist_ok=True)
    for k, (name, label) in enumerate(labels.items()):
        save_jpeg(voc / "JPEGImages" / f"{name}.jpg", scene_image(label.shape, k))
        save_palette_png(voc / "SegmentationClass" / f"{name}.png", label)
    for split, names in splits.items():
        (voc / "ImageSets" / "Segmentation" / f"{split}.txt").write_text(
            "".join(f"{n}\n" for n in names)
        )
    return voc


def write_gtcls(path: Path, segmentation: np.ndarray) -> None:
    """An SBD ``cls/*.mat``: struct ``GTcls`` with ``Boundaries`` (20×1 cell of sparse logical
    boundary maps), ``Segmentation`` (uint8 class indices) and ``CategoriesPresent``."""
    boundaries = np.empty((len(VOC_CLASS_NAMES) - 1, 1), dtype=object)
    for c in range(1, len(VOC_CLASS_NAMES)):
        region = segmentation == c
        edge = (
            region & ~np.pad(region, 1, mode="edge")[2:, 1:-1]
            | region & ~np.pad(region, 1, mode="edge")[1:-1, 2:]
        )
        boundaries[c - 1, 0] = scipy.sparse.csc_matrix(edge)
    present = np.array([[c] for c in np.unique(segmentation) if 0 < c < 255], dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(
        path,
        {
            "GTcls": {
                "Boundaries": boundaries,
                "Segmentation": segmentation.astype(np.uint8),
                "CategoriesPresent": present,
            }
        },
        do_compression=True,
    )


def write_sbd(
    root: Path, labels: Mapping[str, np.ndarray], splits: Mapping[str, Sequence[str]]
) -> Path:
    """A ``benchmark_RELEASE/dataset`` tree under ``root``; returns the ``dataset`` folder."""
    dataset = root / "benchmark_RELEASE" / "dataset"
    for k, (name, label) in enumerate(labels.items()):
        save_jpeg(dataset / "img" / f"{name}.jpg", scene_image(label.shape, 100 + k))
        write_gtcls(dataset / "cls" / f"{name}.mat", label)
        write_gtcls(dataset / "inst" / f"{name}.mat", label)  # present in the real tree, unused
    for split, names in splits.items():
        (dataset / f"{split}.txt").write_text("".join(f"{n}\n" for n in names))
    return dataset


def coco_segmentation(obj: Obj) -> object:
    if obj.encoding == "polygon":
        assert obj.box is not None, "polygons are written for rectangles only"
        x0, y0, x1, y1 = obj.box
        return [[x0, y0, x1, y0, x1, y1, x0, y1]]
    fortran = np.asfortranarray(obj.mask.astype(np.uint8))
    if obj.encoding == "rle":
        rle = mask_utils.encode(fortran)
        return {"size": rle["size"], "counts": rle["counts"].decode("ascii")}
    # Uncompressed RLE (as COCO's crowd annotations): run lengths in column-major order,
    # starting with a run of zeros.
    flat = obj.mask.T.ravel().astype(np.int8)
    changes = np.flatnonzero(np.diff(np.concatenate([[0], flat, [1 - flat[-1]]])))
    runs = np.diff(np.concatenate([[0], changes]))
    counts = runs.tolist()
    assert sum(counts) == obj.mask.size
    return {"size": list(obj.mask.shape), "counts": counts}


def coco_json(
    scenes: Mapping[int, tuple[str, Scene]], shape: tuple[int, int],
    categories: Sequence[Mapping] = COCO_CATEGORIES, voc_to_coco: Mapping[int, int] = VOC_TO_COCO_ID,
) -> dict:  # fmt: skip
    """The instances JSON of ``scenes`` (image id -> (file_name, scene)), objects in reverse
    order (so the loader's overlap rule, not the file order, decides)."""
    images, annotations = [], []
    for image_id, (file_name, scene) in scenes.items():
        images.append(
            {"id": image_id, "file_name": file_name, "width": shape[1], "height": shape[0]}
        )
        for obj in reversed(scene):
            ys, xs = np.nonzero(obj.mask)
            annotations.append(
                {
                    "id": len(annotations) + 1,
                    "image_id": image_id,
                    "category_id": voc_to_coco[obj.voc_class],
                    "segmentation": coco_segmentation(obj),
                    "area": float(obj.mask.sum()),
                    "bbox": [
                        float(xs.min()),
                        float(ys.min()),
                        float(np.ptp(xs) + 1),
                        float(np.ptp(ys) + 1),
                    ],
                    "iscrowd": int(obj.crowd),
                }
            )
    return {
        "info": {"description": "uss-slam test fixture"},
        "licenses": [],
        "images": images,
        "annotations": annotations,
        "categories": list(categories),
    }


def write_coco(
    root: Path,
    scenes: Mapping[int, tuple[str, Scene]],
    shape: tuple[int, int],
    split: str = "train",
    **json_kw: object,
) -> Path:
    """``root/annotations/instances_<split>2017.json`` + ``root/<split>2017/<file_name>``."""
    for k, (file_name, _) in enumerate(scenes.values()):
        save_jpeg(root / f"{split}2017" / file_name, scene_image(shape, 200 + k))
    path = root / "annotations" / f"instances_{split}2017.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(coco_json(scenes, shape, **json_kw)))  # type: ignore[arg-type]
    return root


def write_tum(root: Path, frames: int, shape: tuple[int, int] = (24, 32)) -> Path:
    """A TUM RGB-D sequence folder with ``rgb.txt`` and ``rgb/*.png`` (no depth)."""
    (root / "rgb").mkdir(parents=True)
    stamps = [1305031102.175304 + i / 30 for i in range(frames)]
    files = []
    for i, stamp in enumerate(stamps):
        files.append(f"rgb/{stamp:.6f}.png")
        Image.fromarray(scene_image(shape, 300 + i)).save(root / files[-1])
    write_file_list(root / "rgb.txt", stamps, files)
    return root


def standard_scenes(shape: tuple[int, int] = (40, 48)) -> dict[str, Scene]:
    """Five images: every class, overlaps, crowd, a dog (-> background), and one with only a
    chair / only a monitor / nothing of ours."""
    h, w = shape
    return {
        "2008_000001": [  # person in front of a monitor, chair, crowd of people
            rect(shape, 2, 2, 30, 30, 20),  # monitor (large, polygon)
            rect(shape, 10, 5, 20, 38, 15, encoding="rle"),  # person over the monitor
            ellipse(shape, 38, 30, 7, 6, 9),  # chair (RLE)
            rect(shape, 24, 0, 48, 8, 15, crowd=True, encoding="raw"),  # crowd (uncompressed)
        ],
        "2008_000002": [rect(shape, 5, 5, 25, 25, 15), rect(shape, 30, 10, 40, 20, 12)],
        "2008_000003": [ellipse(shape, 20, 20, 10, 8, 9, encoding="raw")],
        "2008_000004": [rect(shape, 0, 0, w, h // 2, 20), rect(shape, 4, 4, 8, 8, 15)],
        "2008_000005": [rect(shape, 10, 10, 30, 30, 12)],
    }

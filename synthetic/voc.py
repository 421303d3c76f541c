"""A PASCAL VOC 2012-layout segmentation set, rendered in the ``source`` style (or, for the
``appearance`` shift's target, the same content in the ``target`` style: :func:`render_voc_frames`).

Each image is a new random room layout (desks, monitors, chairs, shelves, 1-3 people standing,
walking or seated) seen from a random viewpoint aimed at a person, chair or monitor, 1-3.8 m
away; with ``near`` > 0, that share of the images faces a person 0.6-1.6 m away from chest
height instead (:func:`near_view`). Labels are
palette PNGs with VOC indices (person 15, chair 9, tvmonitor 20, background 0) and a void band
(255) along object outlines, about 5 pixels wide at 500 pixels like the real annotations.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import cv2
import numpy as np
import yaml
from PIL import Image

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX, PROJECT_TO_VOC, voc_palette
from uss_slam.core.progress import progress_bar
from uss_slam.core.tum_io import TUM_CAMERAS

from .motion import look_at
from .output import SynthArgumentError, check_size, staged_output, write_jpeg
from .primitives import PrimArrays
from .renderer import Renderer
from .scene import Scene, random_scene
from .seeding import stream
from .styles import EXPOSURE_TIME, STYLES, NoisePool, target_rgb, to_uint8
from .textures import (
    WARDROBE_IMAGES,
    WARDROBES,
    all_wardrobe_bank,
    texture_bank,
    wardrobe_bank,
)

VOC_VARIANTS = 3
"""Texture banks the set draws from (image ``i`` uses bank ``i % VOC_VARIANTS``)."""
PERSON = CLASS_NAMES.index("person")
MIN_OBJECT_SHARE = 0.01
"""Each image shows at least this share of person / chair / monitor pixels."""
VAL_EVERY = 5
"""Every fifth image goes to ``val.txt``, the others to ``train.txt``."""


@dataclass
class VocSample:
    """One rendered image: ``rgb`` (H, W, 3) uint8; ``labels`` (H, W) uint8 project class ids."""

    name: str
    rgb: np.ndarray
    labels: np.ndarray


def void_width(size: tuple[int, int]) -> int:
    """Width in pixels of the void band (5 px at 500 px, scaled with the image size, >= 1)."""
    return max(1, int(round(5 * max(size) / 500)))


def voc_indices(labels: np.ndarray, band: int) -> np.ndarray:
    """Project class ids (H, W) -> VOC indices with a ``band``-pixel void (255) along outlines."""
    lut = np.zeros(256, np.uint8)
    for ours, voc in PROJECT_TO_VOC.items():
        lut[ours] = voc
    out = lut[labels]
    out[_void_band(labels, band)] = IGNORE_INDEX
    return out


def _void_band(labels: np.ndarray, band: int) -> np.ndarray:
    """(H, W) bool: the ``band``-pixel band along the outlines of ``labels``."""
    kernel = np.ones((3, 3), np.uint8)
    edge = cv2.dilate(labels, kernel) != cv2.erode(labels, kernel)  # 2 px across the outline
    if band > 2:
        edge = cv2.dilate(edge.astype(np.uint8), np.ones((band - 1, band - 1), np.uint8)) > 0
    elif band == 1:
        edge = labels != cv2.erode(labels, np.ones((2, 2), np.uint8))
    return edge


def _inside_something(point: np.ndarray, prims: PrimArrays, margin: float = 0.15) -> bool:
    corners = prims.corners()
    lo = corners.min(axis=1) - margin
    hi = corners.max(axis=1) + margin
    return bool(((point >= lo) & (point <= hi)).all(axis=1).any())


def check_outfits(outfits: str) -> None:
    """``outfits`` must be one of :data:`~.textures.WARDROBES` (else a one-line error)."""
    if outfits not in WARDROBES:
        raise SynthArgumentError(
            f"unknown outfits {outfits!r}; choose one of {', '.join(WARDROBES)}"
        )


@functools.lru_cache(maxsize=2)
def _noise_pool(seed: int, size: tuple[int, int]) -> NoisePool:
    w, h = size
    return NoisePool(seed, 2 * w * h * 3 + 4096)


def render_voc_sample(
    seed: int,
    index: int,
    size: tuple[int, int],
    outfits: str = "classic",
    style: str = "source",
    near: float = 0.0,
) -> VocSample:
    """Render image ``index`` of the set with ``seed`` (deterministic, independent of the others).

    ``outfits``: the people's clothing, one of :data:`~.textures.WARDROBES`. ``style``:
    ``source`` (clean, even light) or ``target`` (the recordings' lighting and the Kinect-like
    sensor of :func:`~.styles.target_rgb`, with the blur of a camera moving during the
    exposure); the content (layout, viewpoint, materials, labels) does not depend on it.
    ``near``: the share of images framed as a person facing a camera at walking distance
    (:func:`near_view`); the others (and every image when 0) are as without it.
    """
    check_outfits(outfits)
    check_near(near)
    if style not in STYLES:
        raise SynthArgumentError(f"unknown style {style!r}; choose one of {', '.join(STYLES)}")
    rng = stream(seed, "voc/view", index)
    w, h = size
    if outfits == "classic":
        bank = texture_bank("source", index % VOC_VARIANTS)
    elif outfits == "varied":
        bank = wardrobe_bank(index % VOC_VARIANTS, index // WARDROBE_IMAGES)
    else:
        # one room bank per wardrobe: a bank is built once for its 20 images
        bank = all_wardrobe_bank(index // WARDROBE_IMAGES, index // WARDROBE_IMAGES)
    # a separate stream: a set with near=0 is the set rendered before the option existed
    close = stream(seed, "voc/near", index)
    is_near = near > 0 and close.uniform() < near
    for attempt in range(200):
        scene: Scene = random_scene(seed, index * 1000 + attempt // 20)
        prims = scene.prims_at(0.0)
        if not len(prims):
            continue
        lo, hi = np.array(scene.room.lo), np.array(scene.room.hi)
        if is_near:
            view = near_view(prims, close)
            if view is None:
                continue
            eye, target = view
        else:
            objects = np.flatnonzero(prims.label > 0)
            if len(objects) == 0:
                continue
            focus = prims.center[objects[int(rng.integers(0, len(objects)))]].astype(np.float64)
            dist = rng.uniform(1.0, 3.8)
            ang = rng.uniform(-math.pi, math.pi)
            eye = np.array([focus[0] + dist * math.cos(ang), focus[1] + dist * math.sin(ang),
                            rng.uniform(0.8, 1.9)])  # fmt: skip
            target = None
        if (eye < lo + 0.25).any() or (eye > hi - 0.25).any() or _inside_something(eye, prims):
            continue
        if target is None:
            target = focus + rng.normal(0, 0.25, 3)
        pose = np.eye(4)
        roll = rng.normal(0, 0.05)
        c, s = math.cos(roll), math.sin(roll)
        pose[:3, :3] = look_at(eye, target) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        pose[:3, 3] = eye
        zoom = rng.uniform(0.8, 1.3)
        base = TUM_CAMERAS["fr3"].scaled(w, h)
        cam = type(base)(base.fx * zoom, base.fy * zoom, base.cx, base.cy, w, h)
        renderer = Renderer(cam)
        res = renderer.render(pose, scene.room, prims, bank, scene.lighting(style))
        if (res.labels > 0).mean() < MIN_OBJECT_SHARE:
            continue
        if style == "source":
            rgb = to_uint8(res.rgb)
        else:
            # a hand-held camera turning at up to ~30 deg/s during the exposure
            sensor = stream(seed, "voc/sensor", index)
            axis = sensor.normal(size=3)
            angle = sensor.uniform(0, math.radians(30)) * EXPOSURE_TIME / 2
            before = pose.copy()
            before[:3, :3] = pose[:3, :3] @ cv2.Rodrigues(axis / np.linalg.norm(axis) * angle)[0]
            flow = renderer.flow(res.depth, pose, before)
            gain = float(sensor.uniform(0.85, 1.15))
            rgb = target_rgb(res.rgb, flow, gain, sensor, _noise_pool(seed, size))
        return VocSample(f"{seed:04d}_{index:06d}", rgb, res.labels)
    raise RuntimeError(f"no usable view for VOC image {index} (seed {seed})")  # pragma: no cover


NEAR_DISTANCE = (0.6, 1.6)
"""Metres from a near view's camera to the person it faces (the TUM walkers' range)."""
NEAR_EYE_HEIGHT = (1.0, 1.6)
"""Height of a near view's camera: a hand-held Kinect at chest height."""


def check_near(near: float) -> None:
    if isinstance(near, bool) or not isinstance(near, (int, float)) or not 0 <= near <= 1:
        raise SynthArgumentError(f"near must be a share in [0, 1], got {near!r}")


def near_view(prims: PrimArrays, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
    """A camera at :data:`NEAR_DISTANCE` from one of the scene's people, at
    :data:`NEAR_EYE_HEIGHT`, looking about level at the person's torso (as a camera carried
    past a walker sees them); None when the scene has no person."""
    people = np.flatnonzero(prims.label == PERSON)
    if len(people) == 0:
        return None
    # the person's parts: the primitives whose centres are within 0.5 m of the picked one's
    pick = prims.center[people[int(rng.integers(0, len(people)))]].astype(np.float64)
    parts = people[np.linalg.norm(prims.center[people, :2] - pick[:2], axis=1) < 0.5]
    torso = prims.center[parts].astype(np.float64).mean(axis=0)
    dist = rng.uniform(*NEAR_DISTANCE)
    ang = rng.uniform(-math.pi, math.pi)
    eye = np.array([torso[0] + dist * math.cos(ang), torso[1] + dist * math.sin(ang),
                    rng.uniform(*NEAR_EYE_HEIGHT)])  # fmt: skip
    target = np.array([torso[0], torso[1], torso[2]]) + rng.normal(0, 0.15, 3)
    return eye, target


def _check_images(images: int, outfits: str) -> None:
    """The ``outfits`` and the image count of :func:`render_voc` and :func:`render_voc_frames`."""
    check_outfits(outfits)
    if isinstance(images, bool) or not isinstance(images, (int, np.integer)) or images < 1:
        raise SynthArgumentError(f"images must be an integer >= 1, got {images!r}")


def render_voc(
    out_dir: str | PathLike[str],
    *,
    images: int,
    size: tuple[int, int] = (320, 240),
    seed: int = 0,
    outfits: str = "classic",
    near: float = 0.0,
    lighting: str = "source",
    overwrite: bool = False,
    progress: bool = False,
) -> Path:
    """Write ``out_dir/VOCdevkit/VOC2012/{JPEGImages, SegmentationClass, ImageSets/Segmentation}``.

    ``images`` JPEGs (quality 90) with palette PNG labels; ``train.txt`` / ``val.txt`` (every
    fifth image) and ``trainval.txt``. Returns the ``.../VOC2012`` path. The folder appears only
    when complete; an existing non-empty ``out_dir`` is an error unless ``overwrite``.
    ``outfits``: the people's clothing (:data:`~.textures.WARDROBES`; ``varied``: every kind of
    fabric and colour, a new wardrobe of 4 outfits every 20 images). ``near``: the share of
    images that face a person at walking distance (:func:`near_view`). ``lighting``: ``source``
    (every image in the source style) or ``mixed`` (each image in the source or the target style,
    drawn per image with even odds: :func:`image_style`), the lighting mix of a broad photo
    collection such as COCO, which the pretraining set of :mod:`uss_slam.pipelines` stands in for.
    """
    _check_images(images, outfits)
    check_near(near)
    if lighting not in LIGHTINGS:
        raise SynthArgumentError(
            f"unknown lighting {lighting!r}; choose one of {', '.join(LIGHTINGS)}"
        )
    size = check_size(size)
    palette = voc_palette().reshape(-1).tolist()
    band = void_width(size)
    with staged_output(out_dir, overwrite) as tmp:
        root = tmp / "VOCdevkit" / "VOC2012"
        jpeg, seg, sets = (
            root / "JPEGImages",
            root / "SegmentationClass",
            root / "ImageSets" / "Segmentation",
        )
        for folder in (jpeg, seg, sets):
            folder.mkdir(parents=True)
        names = []
        for i in progress_bar(range(images), desc="VOC images", unit="img", disable=not progress):
            sample = render_voc_sample(
                seed, i, size, outfits, image_style(seed, i, lighting), near=near
            )
            write_jpeg(jpeg / f"{sample.name}.jpg", sample.rgb)
            png = Image.fromarray(voc_indices(sample.labels, band), mode="P")
            png.putpalette(palette)
            png.save(seg / f"{sample.name}.png", optimize=False, compress_level=6)
            names.append(sample.name)
        val = [n for i, n in enumerate(names) if i % VAL_EVERY == VAL_EVERY - 1]
        train = [n for i, n in enumerate(names) if i % VAL_EVERY != VAL_EVERY - 1]
        for split, items in (("train", train), ("val", val), ("trainval", names)):
            (sets / f"{split}.txt").write_text("".join(f"{n}\n" for n in items), encoding="utf-8")
    return Path(out_dir) / "VOCdevkit" / "VOC2012"


LIGHTINGS = ("source", "mixed")
"""The lightings of a VOC tree (:func:`render_voc`)."""


def image_style(seed: int, index: int, lighting: str) -> str:
    """The style image ``index`` of a VOC tree with ``lighting`` is rendered in: ``source``, or
    under ``mixed`` the source or target style with even odds (its own random stream, so the
    content of every image is the same as under ``source``)."""
    if lighting == "source":
        return "source"
    return "target" if stream(seed, "voc/lighting", index).uniform() < 0.5 else "source"


FRAMES_RATE = 30.0
"""Stamps of :func:`render_voc_frames`' images are 1/30 s apart (they are not a video)."""


def render_voc_frames(
    out_dir: str | PathLike[str],
    *,
    images: int,
    size: tuple[int, int] = (320, 240),
    seed: int = 0,
    outfits: str = "classic",
    style: str = "target",
    near: float = 0.0,
    overwrite: bool = False,
    progress: bool = False,
) -> Path:
    """The VOC-layout images of ``seed`` as a labelled *image folder* in the TUM layout: ``rgb/``
    (PNG), ``labels/`` (uint8 project class ids, void band 255 as in the VOC set), ``rgb.txt``
    (stamps 1/30 s apart) and ``synthetic.yaml``; no depth. This is how the ``appearance``
    shift's target frames are stored, so that the target loader (``TUMFrames``) and
    ``uss-eval --sequence`` read them like a recording's frames. ``near``: as
    :func:`render_voc`'s. Returns ``out_dir``.
    """
    _check_images(images, outfits)
    check_near(near)
    if style not in STYLES:
        raise SynthArgumentError(f"unknown style {style!r}; choose one of {', '.join(STYLES)}")
    size = check_size(size)
    band = void_width(size)
    from uss_slam.core.tum_io import write_file_list

    from .output import write_png

    with staged_output(out_dir, overwrite) as tmp:
        (tmp / "rgb").mkdir()
        (tmp / "labels").mkdir()
        stamps, files = [], []
        for i in progress_bar(range(images), desc=f"VOC-layout frames ({style})", unit="img",
                      disable=not progress):  # fmt: skip
            sample = render_voc_sample(seed, i, size, outfits, style, near)
            stamp = round(1.0 + i / FRAMES_RATE, 6)
            name = f"{stamp:.6f}.png"
            labels = sample.labels.copy()
            labels[_void_band(sample.labels, band)] = IGNORE_INDEX
            write_png(tmp / "rgb" / name, sample.rgb)
            write_png(tmp / "labels" / name, labels)
            stamps.append(stamp)
            files.append(f"rgb/{name}")
        write_file_list(tmp / "rgb.txt", np.array(stamps), files, "color images")
        meta = {
            "generator": "uss-synth voc-frames",
            "images": int(images),
            "size": list(size),
            "seed": int(seed),
            "style": style,
            "outfits": outfits,
        }
        if near:
            meta["near"] = float(near)
        (tmp / "synthetic.yaml").write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
    return Path(out_dir)

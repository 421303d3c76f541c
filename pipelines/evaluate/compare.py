"""``uss-eval compare``: did adaptation help on my target? Two or more exported models on the
same unlabelled target frames, compared without labels (validators, mask agreement) and, with a
few labelled frames, by person IoU and mIoU with bootstrap intervals.

Everything the command reads is checked before the first inference (:func:`plan_compare`); the
frame loop (:func:`run_compare`) holds one batch of frames and a few thumbnails at a time; the
report is written by :mod:`.compare_report` only once everything has run, each file under a
temporary name renamed into place, so a failure leaves nothing under a final name.
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import file_sha256
from uss_slam.core.images import read_colour
from uss_slam.core.onnx_contract import OUTPUT_LABELS, OUTPUT_LOGITS
from uss_slam.core.paths import distinct_folders
from uss_slam.core.seg_metrics import confusion_matrix
from uss_slam.core.tum_io import label_file_name, read_tum_folder
from uss_slam.core.validators import (
    NEEDS_SOURCE,
    AgreementCounter,
    Validator,
    build_validators,
    downsample_maps,
)

from .models import _project_lut

MIN_LABELS = 15
"""Fewer labelled frames than this: a warning with the interval they give."""
THUMB_SIDE = 240
"""Longest side of the contact sheet's thumbnails (pixels)."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


@dataclass
class ModelInput:
    name: str
    path: Path
    session: Any
    class_names: tuple[str, ...]
    lut: np.ndarray | None  # model class index -> project id (None: identical)
    dynamic_channels: tuple[int, ...]  # model channels of the dynamic classes
    sha256: str


@dataclass
class Frame:
    sequence: str
    name: str  # the colour image's file name
    rgb: Path
    labels: np.ndarray | None = None  # (H, W) uint8 project ids, checked


@dataclass
class ComparePlan:
    """Everything :func:`run_compare` needs, checked."""

    models: list[ModelInput]
    frames: list[Frame]
    sequences: list[str]
    dynamic: tuple[str, ...]
    validator_names: list[str]
    validator_params: dict[str, Any]
    source: list[Path] = field(default_factory=list)
    batch: int = 4
    max_side: int = 160
    contact: int = 6

    @property
    def labelled(self) -> int:
        return sum(f.labels is not None for f in self.frames)


def _load_model(path: Path, threads: int | None) -> ModelInput:
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    if path.suffix.lower() != ".onnx" or not path.is_file():
        raise UssSlamError(f"{path}: expected an exported model (.onnx file written by uss-export)")
    seg = OnnxSegmenter(path, threads=threads)  # the contract: inputs, outputs, metadata
    outputs = {o.name for o in seg.session.get_outputs()}
    if OUTPUT_LOGITS not in outputs:
        raise DataFormatError(
            path, f"has no {OUTPUT_LOGITS!r} output: the validators need the softmax"
        )
    names = tuple(seg.metadata.class_names)
    return ModelInput(
        name=path.stem, path=path, session=seg.session, class_names=names,
        lut=_project_lut(names, str(path)), dynamic_channels=(), sha256=file_sha256(path),
    )  # fmt: skip


def check_models(
    paths: Sequence[Path], dynamic: Sequence[str], threads: int | None
) -> list[ModelInput]:
    """Load and check every model: two or more, none twice (same file or same bytes), one class
    list and one input contract for all, each naming the dynamic classes."""
    if len(paths) < 2:
        raise UssSlamError(f"MODEL: expected two or more exported models, got {len(paths)}")
    models: list[ModelInput] = []
    for path in paths:
        model = _load_model(Path(path), threads)
        for other in models:
            if other.path.resolve() == model.path.resolve() or other.sha256 == model.sha256:
                raise UssSlamError(f"{model.path}: the same model as {other.path} (given twice)")
            if other.name == model.name:
                raise UssSlamError(
                    f"{model.path}: the same name {model.name!r} as {other.path}; rename one file"
                )
        if models and model.class_names != models[0].class_names:
            raise DataFormatError(
                model.path, f"classes {list(model.class_names)} differ from {models[0].path}'s "
                f"{list(models[0].class_names)}; compare models of one class list"
            )  # fmt: skip
        missing = [c for c in dynamic if c not in model.class_names]
        if missing:
            raise DataFormatError(
                model.path,
                f"has no class {missing[0]!r} (--dynamic); its classes: {', '.join(model.class_names)}",
            )
        model.dynamic_channels = tuple(model.class_names.index(c) for c in dynamic)
        models.append(model)
    _check_contracts(models)
    return models


def _check_contracts(models: list[ModelInput]) -> None:
    """One input contract (input name, dtype, layout) for all models."""

    def contract(m: ModelInput) -> tuple:
        (inp,) = m.session.get_inputs()
        return inp.name, inp.type, len(inp.shape)

    first = contract(models[0])
    for m in models[1:]:
        if contract(m) != first:
            raise DataFormatError(
                m.path, f"input {contract(m)} differs from {models[0].path}'s {first}"
            )


def _image_size(path: Path) -> tuple[int, int] | None:
    """``(W, H)`` from the file's header, None when it is not a readable image."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except (OSError, UnidentifiedImageError, ValueError):
        return None


def check_sequences(roots: Sequence[Path], stride: int) -> tuple[list[Frame], list[str]]:
    """Every ``stride``-th colour frame of each TUM folder, each image's header read (readable,
    one size per sequence); a folder given twice, without frames, or with an unreadable image:
    one line naming it."""
    if not roots:
        raise UssSlamError("--sequence: expected at least one TUM RGB-D folder of target frames")
    if stride < 1:
        raise UssSlamError(f"--stride: expected an integer >= 1, got {stride}")
    frames: list[Frame] = []
    names: list[str] = []
    for root in distinct_folders(roots, "--sequence"):
        folder = read_tum_folder(root, depth=False, labels=False)
        chosen = folder.frames[::stride]
        name = root.name if root.name not in names else f"{root.parent.name}/{root.name}"
        names.append(name)
        size = None
        for f in chosen:
            if (err := folder.missing(f)) is not None:
                raise err
            wh = _image_size(f.rgb)
            if wh is None:
                raise DataFormatError(f.rgb, "not a readable image (expected a colour PNG or JPEG)")
            if size is not None and wh != size:
                raise DataFormatError(
                    f.rgb, f"is {wh[0]}x{wh[1]}, the sequence's first frame {size[0]}x{size[1]}"
                )
            size = wh
            frames.append(Frame(name, f.rgb.name, f.rgb))
    return frames, names


def attach_labels(
    frames: list[Frame], folders: Sequence[Path], wanted: int | None, classes: int
) -> int:
    """Read label PNGs named as colour frames (``labels/`` of a TUM folder, or any folder of
    them) and attach ``wanted`` of them (evenly spaced; all when None) to their frames; checked:
    each file matches one frame, has its size and only class ids ``< classes`` or 255. Returns
    the number attached."""
    by_name: dict[str, list[Frame]] = {}
    for f in frames:
        by_name.setdefault(label_file_name(f.name), []).append(f)
    found: list[tuple[Frame, Path]] = []
    for folder in folders:
        if not folder.is_dir():
            raise UssSlamError(f"--labels {folder}: not a folder")
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")
        for path in files:
            matches = by_name.get(path.name, [])
            if len(matches) > 1:
                raise DataFormatError(
                    path,
                    f"matches frames of several sequences ({', '.join(m.sequence for m in matches)})",
                )
            if matches:
                found.append((matches[0], path))
        if not any(p.name in by_name for p in files):
            raise UssSlamError(
                f"--labels {folder}: no label PNG named as a compared colour frame (e.g. "
                f"{label_file_name(frames[0].name)})"
            )
    if wanted is not None and wanted > len(found):
        raise UssSlamError(
            f"--label-frames {wanted}: the --labels folders hold {len(found)} label files of "
            "compared frames (use --stride 1, or fewer frames)"
        )
    if wanted is not None:
        keep = (
            np.unique(np.linspace(0, len(found) - 1, wanted).round().astype(int)) if wanted else []
        )
        found = [found[i] for i in keep]
    from uss_slam.slam_eval.sequence import read_labels

    for frame, path in found:
        w, h = _image_size(frame.rgb) or (0, 0)
        labels = read_labels(path, (h, w), frame.name)
        bad = np.unique(labels[(labels >= classes) & (labels != IGNORE_INDEX)])
        if bad.size:
            raise DataFormatError(
                path, f"class id {int(bad[0])} is not a class (expected 0..{classes - 1} or 255)"
            )
        frame.labels = labels
    return len(found)


def source_images(folder: Path, count: int) -> list[Path]:
    """``count`` evenly spaced images (PNG / JPEG, sorted by name) of ``folder`` (recursively)."""
    if not folder.is_dir():
        raise UssSlamError(f"--source {folder}: not a folder")
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    if len(files) < 2:
        raise UssSlamError(
            f"--source {folder}: expected source images (PNG or JPEG), found {len(files)}"
        )
    picks = np.unique(np.linspace(0, len(files) - 1, min(count, len(files))).round().astype(int))
    chosen = [files[i] for i in picks]
    for path in chosen:
        if _image_size(path) is None:
            raise DataFormatError(path, "not a readable image")
    return chosen


# ------------------------------------------------------------------------ the frame loop


def read_rgb(path: Path) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB of a colour frame (:func:`uss_slam.core.images.read_colour`)."""
    return cv2.cvtColor(read_colour(path), cv2.COLOR_BGR2RGB)


def batches(paths: Sequence[Path], size: int) -> Iterator[tuple[int, np.ndarray]]:
    """``(first index, (N, H, W, 3) uint8)`` of consecutive equal-size images, up to ``size``."""
    start, batch = 0, []
    for k, path in enumerate(paths):
        rgb = read_rgb(path)
        if batch and (len(batch) == size or rgb.shape != batch[0].shape):
            yield start, np.stack(batch)
            start, batch = k, []
        batch.append(rgb)
    if batch:
        yield start, np.stack(batch)


def infer(model: ModelInput, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(N, C, H, W)`` float32 softmax and ``(N, H, W)`` uint8 project labels of ``images``."""
    labels, logits = model.session.run([OUTPUT_LABELS, OUTPUT_LOGITS], {"image": images})
    if (
        logits.ndim != 4
        or logits.shape[1] != len(model.class_names)
        or logits.shape[2:] != images.shape[1:3]
    ):
        raise DataFormatError(
            model.path,
            f"output {OUTPUT_LOGITS!r} has shape {logits.shape} for input {images.shape}",
        )
    logits = logits - logits.max(axis=1, keepdims=True)
    np.exp(logits, out=logits)
    logits /= logits.sum(axis=1, keepdims=True)
    return logits, labels if model.lut is None else model.lut[labels]


@dataclass
class CompareResult:
    plan: ComparePlan
    scores: dict[str, dict[str, float]]  # model -> validator -> score
    agreement: dict[tuple[int, int], Any]  # (a, b) -> MaskAgreement
    matrices: np.ndarray | None  # (M, L, C, C) per labelled frame, or None
    clusters: list[str]  # the sequence of each labelled frame
    contact: list[tuple[float, int, np.ndarray, list[np.ndarray]]]  # (differ, frame, thumb, labels)
    seconds: float
    dynamic_share: dict[str, float] = field(default_factory=dict)


def _thumb(image: np.ndarray, interpolation: int) -> np.ndarray:
    h, w = image.shape[:2]
    s = min(1.0, THUMB_SIDE / max(h, w))
    return cv2.resize(
        image, (max(1, round(w * s)), max(1, round(h * s))), interpolation=interpolation
    )


def spread(candidates: list, count: int, gap: int) -> list:
    """Up to ``count`` of ``(differ, frame index, ...)`` candidates, most differing first, none
    within ``gap`` frames of one already chosen (neighbouring frames show the same thing)."""
    chosen: list = []
    for item in sorted(candidates, key=lambda t: (-t[0], t[1])):
        if len(chosen) < count and all(abs(item[1] - c[1]) >= gap for c in chosen):
            chosen.append(item)
    return chosen


def run_compare(plan: ComparePlan, progress: Any = None) -> CompareResult:
    """Run every model on every frame, one batch at a time (see the module docstring)."""
    t0 = time.perf_counter()
    models = plan.models
    vals: list[dict[str, Validator]] = [
        build_validators(plan.validator_names, {
            **plan.validator_params, "dynamic_share": {"classes": m.dynamic_channels}
        }, "--validators")
        for m in models
    ]  # fmt: skip
    if plan.source:
        for m, v in zip(models, vals, strict=True):
            for _, images in batches(plan.source, plan.batch):
                small = downsample_maps(infer(m, images)[0], plan.max_side)
                for name in NEEDS_SOURCE & set(v):
                    v[name].update_source(small)  # type: ignore[attr-defined]
    pairs = [(a, b) for a in range(len(models)) for b in range(a + 1, len(models))]
    counters = {p: AgreementCounter() for p in pairs}
    dyn_ids = [CLASS_NAMES.index(c) for c in plan.dynamic]
    n_cls = len(CLASS_NAMES)
    matrices: list[np.ndarray] = []
    clusters: list[str] = []
    contact: list[tuple[float, int, np.ndarray, list[np.ndarray]]] = []
    for start, images in batches([f.rgb for f in plan.frames], plan.batch):
        labels = []
        for m, v in zip(models, vals, strict=True):
            prob, lab = infer(m, images)
            small = downsample_maps(prob, plan.max_side)
            for validator in v.values():
                validator.update(small)
            labels.append(lab)
        masks = [np.isin(lab, dyn_ids) for lab in labels]
        for k in range(len(images)):
            index = start + k
            worst = 0.0
            for a, b in pairs:
                counters[(a, b)].update(masks[a][k], masks[b][k])
                worst = max(worst, counters[(a, b)].differ[-1])
            item = (worst, index, _thumb(images[k], cv2.INTER_AREA),
                    [_thumb(lab[k], cv2.INTER_NEAREST) for lab in labels])  # fmt: skip
            if len(contact) < 4 * plan.contact:  # candidates: spread out at the end
                heapq.heappush(contact, item)
            elif worst > contact[0][0]:
                heapq.heapreplace(contact, item)
            frame = plan.frames[index]
            if frame.labels is not None:
                matrices.append(
                    np.stack([confusion_matrix(frame.labels, lab[k], n_cls) for lab in labels])
                )
                clusters.append(frame.sequence)
        if progress is not None:
            progress(start + len(images), len(plan.frames))
    return CompareResult(
        plan=plan,
        scores={
            m.name: {n: v.score() for n, v in val.items()}
            for m, val in zip(models, vals, strict=True)
        },
        agreement={p: c.result() for p, c in counters.items()},
        matrices=np.stack(matrices, axis=1) if matrices else None,
        clusters=clusters,
        contact=spread(contact, plan.contact, max(1, len(plan.frames) // (4 * plan.contact))),
        seconds=time.perf_counter() - t0,
    )

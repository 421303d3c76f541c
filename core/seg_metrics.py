"""Segmentation metrics, torch-free: the one implementation of the confusion matrix, per-class
IoU and mIoU, and the dynamic-mask frame metrics of the robust-semantic-mapping paper.

Conventions: label maps are ``(H, W)`` integer arrays of project class ids; truth pixels equal to
:data:`~uss_slam.core.classes.IGNORE_INDEX` (255) count nowhere. A confusion matrix is
``(C, C)`` int64 with rows = truth, columns = prediction.

IoU of class ``c``: ``TP / (TP + FP + FN)`` over all pixels, NaN when the class is absent from
both truth and prediction; mIoU is the mean over the classes whose IoU is defined (NaN if none).

Dynamic-mask metrics (the paper's Table III, equations 6-10) for a mask of dynamic classes
(default: person) against the truth's, from counts ``TP, FP, TN, FN``::

    FPR = FP / (FP + TN)          FNR = FN / (TP + FN)
    Re  = TP / (TP + FN)          Pr  = TP / (TP + FP)
    PWC = (FN + FP) / (TP + FN + FP + TN)

The paper counts *frames*: TP = the class is in the frame and was correctly segmented, FN = it
is in the frame but was not, FP = it is not in the frame but something was segmented as it,
TN = neither. "Correctly segmented" is ours to fix: the frame's predicted mask has IoU >=
``iou_threshold`` (default 0.5) with the true mask. The same formulas over *pixels* give the
pixel-level rates, reported pooled over all frames and as the mean of per-frame rates. Rates
are fractions (the paper prints percentages); an undefined rate (zero denominator) is NaN.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from uss_slam.core.classes import IGNORE_INDEX
from uss_slam.core.errors import UssSlamError

RATE_NAMES: tuple[str, ...] = ("FPR", "FNR", "recall", "precision", "PWC")
"""The five rates of the paper's Table III, in its order."""


def _same_shape(truth: np.ndarray, prediction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both label maps as arrays; an error unless they have one shape."""
    truth = np.asarray(truth)
    prediction = np.asarray(prediction)
    if truth.shape != prediction.shape:
        raise UssSlamError(
            f"prediction shape {prediction.shape} differs from the truth's {truth.shape}"
        )
    return truth, prediction


def confusion_matrix(truth: np.ndarray, prediction: np.ndarray, num_classes: int) -> np.ndarray:
    """``(C, C)`` int64 pixel counts of (truth, prediction) over pixels whose truth is not 255.

    ``truth`` values must be class ids ``< num_classes`` or 255, ``prediction`` values class ids;
    anything else is an error (never silently dropped).
    """
    truth, prediction = _same_shape(truth, prediction)
    n = int(num_classes)
    valid = truth != IGNORE_INDEX
    t = truth[valid].astype(np.int64)
    p = prediction[valid].astype(np.int64)
    for name, values in (("truth", t), ("prediction", p)):
        if values.size and (values.min() < 0 or values.max() >= n):
            bad = values[(values < 0) | (values >= n)][0]
            raise UssSlamError(
                f"{name} holds class id {bad}; expected 0..{n - 1}"
                + (" or 255 (ignore)" if name == "truth" else "")
            )
    return np.bincount(t * n + p, minlength=n * n).reshape(n, n)


def iou_per_class(matrix: np.ndarray) -> np.ndarray:
    """``(C,)`` float64 IoU per class from a confusion matrix; NaN for a class absent from both
    truth and prediction."""
    matrix = np.asarray(matrix, dtype=np.float64)
    tp = np.diag(matrix)
    union = matrix.sum(0) + matrix.sum(1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, tp / np.where(union > 0, union, 1.0), np.nan)


def mean_iou(iou: np.ndarray) -> float:
    """Mean of the defined (non-NaN) IoUs; NaN when none is defined."""
    iou = np.asarray(iou, dtype=np.float64)
    defined = iou[~np.isnan(iou)]
    return float(defined.mean()) if defined.size else math.nan


def _or_none(value: float) -> float | None:
    return None if math.isnan(value) else float(value)


def iou_report(matrix: np.ndarray, class_names: Sequence[str]) -> dict[str, Any]:
    """``{"mIoU": m, "IoU": {name: iou}}`` with ``None`` for undefined values (JSON-ready)."""
    iou = iou_per_class(matrix)
    if len(iou) != len(class_names):
        raise UssSlamError(f"{len(class_names)} class names for a {len(iou)}-class matrix")
    return {
        "mIoU": _or_none(mean_iou(iou)),
        "IoU": {name: _or_none(float(v)) for name, v in zip(class_names, iou, strict=True)},
    }


# ------------------------------------------------------------------------ dynamic-mask metrics


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0 else math.nan


@dataclass(frozen=True)
class BinaryCounts:
    """True / false positives and negatives of a binary decision (pixels or frames)."""

    tp: int = 0
    fp: int = 0
    tn: int = 0
    fn: int = 0

    def __add__(self, other: BinaryCounts) -> BinaryCounts:
        return BinaryCounts(
            self.tp + other.tp, self.fp + other.fp, self.tn + other.tn, self.fn + other.fn
        )

    @property
    def total(self) -> int:
        return self.tp + self.fp + self.tn + self.fn

    @property
    def iou(self) -> float:
        """``TP / (TP + FP + FN)`` (NaN when both masks are empty)."""
        return _ratio(self.tp, self.tp + self.fp + self.fn)

    def rates(self) -> dict[str, float]:
        """FPR, FNR, recall, precision and PWC (equations 6-10), NaN when undefined."""
        return {
            "FPR": _ratio(self.fp, self.fp + self.tn),
            "FNR": _ratio(self.fn, self.tp + self.fn),
            "recall": _ratio(self.tp, self.tp + self.fn),
            "precision": _ratio(self.tp, self.tp + self.fp),
            "PWC": _ratio(self.fn + self.fp, self.total),
        }

    def as_dict(self) -> dict[str, int]:
        return {"TP": self.tp, "FP": self.fp, "TN": self.tn, "FN": self.fn}


def class_mask(labels: np.ndarray, class_ids: Iterable[int]) -> np.ndarray:
    """``(H, W)`` bool: pixels whose label is one of ``class_ids``."""
    return np.isin(labels, np.fromiter(class_ids, dtype=np.int64))


def mask_counts(
    truth: np.ndarray, prediction: np.ndarray, class_ids: Iterable[int]
) -> BinaryCounts:
    """Pixel counts of the mask of ``class_ids`` in ``prediction`` against ``truth``'s (label
    maps; truth pixels equal to 255 count nowhere)."""
    truth, prediction = _same_shape(truth, prediction)
    ids = list(class_ids)
    valid = truth != IGNORE_INDEX
    t = class_mask(truth, ids) & valid
    p = class_mask(prediction, ids) & valid
    tp = int(np.count_nonzero(t & p))
    fp = int(np.count_nonzero(p)) - tp
    fn = int(np.count_nonzero(t)) - tp
    return BinaryCounts(tp=tp, fp=fp, fn=fn, tn=int(np.count_nonzero(valid)) - tp - fp - fn)


def frame_outcome(
    pixels: BinaryCounts, iou_threshold: float = 0.5, min_pixels: int = 1
) -> BinaryCounts:
    """The paper's classification of one frame from its pixel counts (exactly one count is 1).

    The class is *in* the frame when its true mask has ``>= min_pixels`` pixels, *segmented*
    when the predicted mask has ``>= min_pixels``; correctly segmented = IoU >= ``iou_threshold``.
    """
    if not 0.0 < iou_threshold <= 1.0:
        raise UssSlamError(f"iou_threshold must be in (0, 1], got {iou_threshold}")
    if min_pixels < 1:
        raise UssSlamError(f"min_pixels must be >= 1, got {min_pixels}")
    present = pixels.tp + pixels.fn >= min_pixels
    predicted = pixels.tp + pixels.fp >= min_pixels
    if present:
        correct = predicted and pixels.iou >= iou_threshold
        return BinaryCounts(tp=1) if correct else BinaryCounts(fn=1)
    return BinaryCounts(fp=1) if predicted else BinaryCounts(tn=1)


def _json_rates(rates: dict[str, float]) -> dict[str, float | None]:
    return {k: _or_none(v) for k, v in rates.items()}


def mask_metrics(
    per_frame: Sequence[BinaryCounts], iou_threshold: float = 0.5, min_pixels: int = 1
) -> dict[str, Any]:
    """The dynamic-mask metrics of a sequence of frames from each frame's pixel counts.

    Returns (JSON-ready, ``None`` for undefined rates)::

        {"frames": {"counts": {TP, FP, TN, FN}, FPR, FNR, recall, precision, PWC,
                    "iou_threshold": t, "min_pixels": m},        # the paper's Table III
         "pixels_pooled": {"counts": {...}, FPR, ...},            # all frames' pixels together
         "pixels_mean": {FPR, ...},                               # mean of per-frame rates
         "frame_count": N}

    ``pixels_mean`` averages each rate over the frames where it is defined (e.g. recall over
    frames that contain the class); ``None`` if it is defined in none.
    """
    frames = BinaryCounts()
    pooled = BinaryCounts()
    per_rate: dict[str, list[float]] = {name: [] for name in RATE_NAMES}
    for counts in per_frame:
        frames = frames + frame_outcome(counts, iou_threshold, min_pixels)
        pooled = pooled + counts
        for name, value in counts.rates().items():
            if not math.isnan(value):
                per_rate[name].append(value)
    return {
        "frames": {
            "counts": frames.as_dict(),
            **_json_rates(frames.rates()),
            "iou_threshold": float(iou_threshold),
            "min_pixels": int(min_pixels),
        },
        "pixels_pooled": {"counts": pooled.as_dict(), **_json_rates(pooled.rates())},
        "pixels_mean": {
            name: (float(np.mean(values)) if values else None) for name, values in per_rate.items()
        },
        "frame_count": len(per_frame),
    }

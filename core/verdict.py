"""Statistics of model comparison, torch-free: Musgrave's weighted Spearman correlation (how well
a validator ranks checkpoints), a bootstrap over frames clustered by sequence (an IoU's interval
and two models' paired difference) and the labelled frames a difference would need.

IoUs here are pooled over the frames drawn: each frame contributes its ``(C, C)`` confusion
matrix (rows truth, columns prediction), and a draw's IoU of class ``c`` is
``TP / (TP + FP + FN)`` of the summed matrices, as ``uss-eval`` reports it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import rankdata

from uss_slam.core.errors import UssSlamError

Z95 = 1.959963984540054
"""The two-sided 95% normal quantile."""


def weighted_ranks(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted ranks: each value's rank is the total weight of the smaller values plus the
    mean weight of its tie group times ``(count + 1) / 2`` (a tie group shares one rank; with unit
    weights this is the ordinary average rank)."""
    _, inverse, counts = np.unique(rankdata(x), return_inverse=True, return_counts=True)
    mass = np.bincount(inverse, weights=w)
    below = np.cumsum(mass) - mass
    return below[inverse] + ((counts + 1) / 2 * (mass / counts))[inverse]


def weighted_pearson(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """Pearson correlation with observation weights ``w``; NaN when either side is constant."""
    w = w / w.sum()
    mx, my = np.sum(w * x), np.sum(w * y)
    cov = np.sum(w * (x - mx) * (y - my))
    var = np.sum(w * (x - mx) ** 2) * np.sum(w * (y - my) ** 2)
    return float(cov / math.sqrt(var)) if var > 0 else float("nan")


def weighted_spearman(
    scores: Sequence[float], accuracy: Sequence[float], power: float = 2.0
) -> float:
    """Musgrave et al.'s weighted Spearman correlation of validator ``scores`` (higher = the
    validator prefers it) with the true ``accuracy`` of the same checkpoints.

    Reference: Musgrave, Belongie & Lim, "Benchmarking Validation Methods for Unsupervised Domain
    Adaptation" (2021) and their powerful-benchmarker: each checkpoint weighs
    ``(dense rank of its score / largest dense rank) ** power``, so the checkpoints a validator
    would pick count most; the correlation is the weighted Pearson correlation of the weighted
    ranks of both. Non-finite scores count as the worst score. In ``[-1, 1]``."""
    s = np.asarray(scores, np.float64).copy()
    a = np.asarray(accuracy, np.float64)
    if s.shape != a.shape or s.ndim != 1 or len(s) < 3:
        raise UssSlamError(
            f"weighted_spearman: expected two equal 1-D arrays of >= 3, got {s.shape}, {a.shape}"
        )
    finite = np.isfinite(s)
    if not finite.any():
        return float("nan")
    s[~finite] = s[finite].min()
    dense = rankdata(s, method="dense").astype(np.float64)
    w = (dense / dense.max()) ** power
    return weighted_pearson(weighted_ranks(s, w), weighted_ranks(a, w), w)


def iou_from_matrix(matrix: np.ndarray) -> np.ndarray:
    """Per-class IoU ``(C,)`` of a ``(C, C)`` confusion matrix; NaN where a class is absent
    from both truth and prediction."""
    tp = np.diag(matrix).astype(np.float64)
    union = matrix.sum(axis=0) + matrix.sum(axis=1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, tp / np.maximum(union, 1), np.nan)


def miou(matrix: np.ndarray) -> float:
    """Mean of the defined IoUs of ``matrix`` (NaN if none)."""
    iou = iou_from_matrix(matrix)
    return float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")


@dataclass(frozen=True)
class Interval:
    """A point estimate with its 95% percentile bootstrap interval and standard error."""

    value: float
    low: float
    high: float
    se: float

    def excludes_zero(self) -> bool:
        return bool(self.low > 0 or self.high < 0)

    def text(self, signed: bool = False, scale: float = 100.0) -> str:
        """``"41.2 [38.0, 44.9]"`` (points, ``scale`` 100); ``signed``: ``"+1.3 [-0.4, 2.9]"``."""
        value = f"{self.value * scale:+.1f}" if signed else f"{self.value * scale:.1f}"
        return f"{value} [{self.low * scale:.1f}, {self.high * scale:.1f}]"


def cluster_draws(clusters: Sequence[str], draws: int, seed: int) -> list[np.ndarray]:
    """``draws`` bootstrap resamples of frame indices, two-stage: the clusters (sequences) drawn
    with replacement, then frames with replacement within each drawn cluster. With one cluster
    this is the ordinary frame bootstrap."""
    rng = np.random.default_rng(seed)
    groups: dict[str, list[int]] = {}
    for index, cluster in enumerate(clusters):
        groups.setdefault(cluster, []).append(index)
    members = [np.array(v) for v in groups.values()]
    out = []
    for _ in range(draws):
        picked = rng.integers(len(members), size=len(members)) if len(members) > 1 else [0]
        out.append(np.concatenate([rng.choice(members[g], size=len(members[g])) for g in picked]))
    return out


def _interval(point: float, samples: np.ndarray) -> Interval:
    samples = samples[np.isfinite(samples)]
    if samples.size == 0 or not np.isfinite(point):
        return Interval(point, float("nan"), float("nan"), float("nan"))
    low, high = np.percentile(samples, [2.5, 97.5])
    return Interval(point, float(low), float(high), float(samples.std(ddof=1)))


@dataclass(frozen=True)
class ScoreIntervals:
    """Per model: person IoU (``cls``) and mIoU intervals; per ordered pair: paired differences."""

    iou: list[Interval]
    miou: list[Interval]
    diff_iou: dict[tuple[int, int], Interval]
    diff_miou: dict[tuple[int, int], Interval]


def bootstrap_scores(
    matrices: np.ndarray, clusters: Sequence[str], cls: int, draws: int = 2000, seed: int = 0
) -> ScoreIntervals:
    """Intervals from ``matrices`` ``(M, F, C, C)``: M models' per-frame confusion matrices on the
    same F frames, ``clusters`` the sequence of each frame; the same draws for every model, so
    that differences are paired. ``cls``: the class whose IoU is reported (person)."""
    m = matrices.shape[0]
    point_iou = [iou_from_matrix(matrices[k].sum(0))[cls] for k in range(m)]
    point_miou = [miou(matrices[k].sum(0)) for k in range(m)]
    samples_iou = np.empty((draws, m))
    samples_miou = np.empty((draws, m))
    for d, idx in enumerate(cluster_draws(clusters, draws, seed)):
        for k in range(m):
            pooled = matrices[k, idx].sum(0)
            samples_iou[d, k] = iou_from_matrix(pooled)[cls]
            samples_miou[d, k] = miou(pooled)
    pairs = [(a, b) for a in range(m) for b in range(m) if a < b]
    return ScoreIntervals(
        iou=[_interval(point_iou[k], samples_iou[:, k]) for k in range(m)],
        miou=[_interval(point_miou[k], samples_miou[:, k]) for k in range(m)],
        diff_iou={
            (a, b): _interval(point_iou[b] - point_iou[a], samples_iou[:, b] - samples_iou[:, a])
            for a, b in pairs
        },
        diff_miou={
            (a, b): _interval(
                point_miou[b] - point_miou[a], samples_miou[:, b] - samples_miou[:, a]
            )
            for a, b in pairs
        },
    )


def frames_needed(diff: Interval, frames: int) -> int | None:
    """Labelled frames at which a difference of ``diff.value`` would have a 95% interval that
    excludes 0, if the spread per frame stays as measured (``se`` shrinks as 1/sqrt(frames)):
    ``frames * (1.96 se / |value|)^2``, rounded up; None when the difference is 0 or unknown."""
    if not (np.isfinite(diff.se) and np.isfinite(diff.value)) or diff.value == 0:
        return None
    return max(frames, math.ceil(frames * (Z95 * diff.se / abs(diff.value)) ** 2))


def interval_halfwidth_at(se: float, frames: int, planned: int) -> float:
    """The 95% half-width (``1.96 se``) that ``se`` measured on ``frames`` frames implies at
    ``planned`` frames."""
    return Z95 * se * math.sqrt(frames / max(planned, 1))


def separated(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """The one rule for "separated": two ranges ``(low, high)`` are separated only when they do
    not overlap (touching counts as overlapping)."""
    return bool(a[1] < b[0] or b[1] < a[0])

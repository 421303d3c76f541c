"""Label-free validators of a segmenter on unlabelled target frames, torch-free.

A validator scores a model from its softmax maps on target frames, without target labels, so
that a user can compare checkpoints or models where adaptation is used: on a target that has
none. Musgrave et al. ("Benchmarking Validation Methods for Unsupervised Domain Adaptation",
2021) found that such scores agree with target accuracy only sometimes: what one is worth is
what its calibration on a labelled benchmark shows (``docs/results/validators.md``).

Each validator is an accumulator over batches, so that memory is bounded by one batch::

    v = Entropy()
    for prob in batches:            # (N, C, H, W) float softmax maps, channels sum to 1
        v.update(prob)
    v.score()                       # one float; ``v.higher_is_better`` says which way is better

``prob`` is the softmax of the model's logits at any resolution (the callers downsample: every
validator here is a mean over pixels or a sample of them). Names (``VALIDATORS``):

- ``entropy``: minus the mean per-pixel entropy (PyTorch Adapt's ``EntropyValidator``).
- ``im``: information maximisation, minus the mean entropy plus the entropy of the mean
  prediction (``IMValidator`` = ``EntropyValidator`` + ``DiversityValidator``).
- ``snd``: soft neighbourhood density (Saito et al., "Tune it the Right Way", ICCV 2021;
  ``SNDValidator``) on pixels sampled per image.
- ``probe``: domain separability, the held-out accuracy of a small classifier trained fresh to
  tell source from target softmax maps (lower: the domains look alike to it); it needs the source
  maps too (``update_source``).
- ``dynamic_share``: the predicted share of the dynamic classes' pixels (descriptive: no
  direction is better a priori; its calibration says whether it tracks accuracy).

The BatchNorm-statistics distance needs the torch model (``uss_slam.train.validation``); the
pairwise mask agreement of two models is :func:`mask_agreement`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from uss_slam.core.errors import UssSlamError

EPS = 1e-12
"""Added inside every logarithm: ``0 log 0`` counts as 0."""


def _check_prob(prob: np.ndarray, who: str) -> np.ndarray:
    """``prob`` as float64 ``(N, C, H, W)``; one line naming ``who`` for anything else."""
    prob = np.asarray(prob)
    if prob.ndim != 4 or prob.shape[1] < 2 or not np.issubdtype(prob.dtype, np.floating):
        raise UssSlamError(
            f"{who}: expected (N, C, H, W) float softmax maps with C >= 2, got shape "
            f"{prob.shape} and dtype {prob.dtype}"
        )
    return prob.astype(np.float64, copy=False)


def downsample_maps(prob: np.ndarray, max_side: int = 160) -> np.ndarray:
    """``(N, C, H, W)`` softmax maps area-averaged (``cv2.INTER_AREA``) so that the longer side
    is at most ``max_side`` pixels (unchanged when it already is): what every caller feeds the
    validators, so that a score does not depend on the frames' resolution, and costs little.
    Area averages of probability vectors are probability vectors."""
    prob = np.asarray(prob, np.float32)
    n, c, h, w = prob.shape
    scale = max_side / max(h, w)
    if scale >= 1:
        return prob
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    out = np.empty((n, c, size[1], size[0]), np.float32)
    for i in range(n):
        # cv2 resizes up to 512 channels at once on an (H, W, C) array
        out[i] = (
            cv2.resize(prob[i].transpose(1, 2, 0), size, interpolation=cv2.INTER_AREA)
            .reshape(size[1], size[0], c)
            .transpose(2, 0, 1)
        )
    return out


def pixel_rows(prob: np.ndarray) -> np.ndarray:
    """``(N, C, H, W)`` -> ``(N*H*W, C)``: one row per pixel."""
    n, c, h, w = prob.shape
    return prob.transpose(0, 2, 3, 1).reshape(n * h * w, c)


def entropy_rows(rows: np.ndarray) -> np.ndarray:
    """Entropy in nats of each row of ``(M, C)`` probabilities: ``-sum p log p`` -> ``(M,)``."""
    return -np.sum(rows * np.log(rows + EPS), axis=1)


class Validator:
    """Base: ``update(prob)`` per batch, ``score()`` at the end, ``reset()`` to start again.
    ``higher_is_better``: True, False, or None (descriptive: no direction is better)."""

    name = "validator"
    higher_is_better: bool | None = True

    def update(self, prob: np.ndarray) -> None:
        raise NotImplementedError

    def score(self) -> float:
        raise NotImplementedError

    def reset(self) -> None:
        raise NotImplementedError


class Entropy(Validator):
    """Minus the mean per-pixel prediction entropy (nats) over every pixel of every frame.

    Reference: PyTorch Adapt's ``EntropyValidator`` (``-mean(entropy(p))``, ``layer="preds"``);
    the entropy-minimisation view of Grandvalet & Bengio (2005), ADVENT (Vu et al., CVPR 2019).
    Range ``[-log C, 0]``; higher (more confident) is better."""

    name = "entropy"

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._sum, self._count = 0.0, 0

    def update(self, prob: np.ndarray) -> None:
        rows = pixel_rows(_check_prob(prob, self.name))
        self._sum += float(entropy_rows(rows).sum())
        self._count += rows.shape[0]

    def score(self) -> float:
        return -self._sum / self._count if self._count else float("nan")


class InformationMaximization(Validator):
    """Information maximisation: ``-mean_pixels H(p) + H(mean_pixels p)`` (nats).

    Reference: PyTorch Adapt's ``IMValidator`` = ``EntropyValidator`` + ``DiversityValidator``
    (the diversity term is the entropy of the mean prediction over all pixels); Shi & Sha (ICML
    2012), SHOT (Liang et al., ICML 2020). Higher is better: confident per pixel, varied overall."""

    name = "im"

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._entropy = Entropy()
        self._mass: np.ndarray | None = None
        self._count = 0

    def update(self, prob: np.ndarray) -> None:
        rows = pixel_rows(_check_prob(prob, self.name))
        self._entropy.update(prob)
        mass = rows.sum(axis=0)
        self._mass = mass if self._mass is None else self._mass + mass
        self._count += rows.shape[0]

    def score(self) -> float:
        if self._mass is None:
            return float("nan")
        mean = self._mass / self._count
        return self._entropy.score() + float(entropy_rows(mean[None])[0])


class SoftNeighborhoodDensity(Validator):
    """Soft neighbourhood density on ``pixels_per_image`` pixels sampled per frame (seeded).

    Reference: Saito et al., "Tune it the Right Way: Unsupervised Validation of Domain Adaptation
    via Soft Neighborhood Density" (ICCV 2021), as PyTorch Adapt's ``SNDValidator``: cosine
    similarity between the samples' probability vectors, each row without its own entry, a
    softmax over the row at temperature ``temperature`` (0.05), and the mean entropy of the rows.
    Higher is better (dense neighbourhoods: target samples cluster). The similarity is computed
    in blocks of ``block`` rows (memory ``block x samples``); beyond ``max_samples`` samples a
    seeded subset of that many is scored (time and memory bounded whatever the frame count)."""

    name = "snd"

    def __init__(
        self, pixels_per_image: int = 32, temperature: float = 0.05, seed: int = 0,
        block: int = 256, max_samples: int = 8192,
    ) -> None:  # fmt: skip
        if pixels_per_image < 1 or temperature <= 0 or max_samples < 2:
            raise UssSlamError(
                f"snd: expected pixels_per_image >= 1, temperature > 0 and max_samples >= 2, "
                f"got {pixels_per_image}, {temperature} and {max_samples}"
            )
        self.pixels_per_image, self.temperature = int(pixels_per_image), float(temperature)
        self.seed, self.block, self.max_samples = seed, block, int(max_samples)
        self.reset()

    def reset(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._samples: list[np.ndarray] = []

    def update(self, prob: np.ndarray) -> None:
        prob = _check_prob(prob, self.name)
        n, c, h, w = prob.shape
        k = min(self.pixels_per_image, h * w)
        for image in prob:
            chosen = self._rng.choice(h * w, size=k, replace=False)
            self._samples.append(image.reshape(c, h * w)[:, chosen].T)

    def score(self) -> float:
        if not self._samples:
            return float("nan")
        feats = np.concatenate(self._samples).astype(np.float32)
        if len(feats) < 2:
            return float("nan")
        if len(feats) > self.max_samples:  # a seeded subset: time and memory stay bounded
            keep = np.random.default_rng(self.seed + 1).choice(
                len(feats), self.max_samples, replace=False
            )
            feats = feats[np.sort(keep)]
        feats = feats / np.maximum(np.linalg.norm(feats, axis=1, keepdims=True), EPS)
        total, m = 0.0, len(feats)
        for start in range(0, m, self.block):
            sim = feats[start : start + self.block] @ feats.T / self.temperature
            rows = np.arange(sim.shape[0])
            sim[rows, rows + start] = -np.inf  # each sample without itself
            sim -= sim.max(axis=1, keepdims=True)
            p = np.exp(sim)
            p /= p.sum(axis=1, keepdims=True)
            total += float(-(p * np.log(p + EPS)).sum(axis=1, dtype=np.float64).sum())
        return total / m


def pooled_features(prob: np.ndarray, grid: int) -> np.ndarray:
    """``(N, C, H, W)`` softmax maps -> ``(N, C*grid*grid)``: each class map averaged over a
    ``grid x grid`` layout of cells (``cv2.INTER_AREA``), the probe's input."""
    n, c, h, w = prob.shape
    out = np.empty((n, c, grid, grid))
    for i in range(n):
        for j in range(c):
            out[i, j] = cv2.resize(prob[i, j], (grid, grid), interpolation=cv2.INTER_AREA)
    return out.reshape(n, -1)


def logistic_fit(
    x: np.ndarray, y: np.ndarray, l2: float = 1e-2, iterations: int = 50
) -> np.ndarray:
    """L2-regularised logistic regression by Newton's method: ``x`` ``(M, D)`` features (a
    constant column is added), ``y`` ``(M,)`` in {0, 1} -> weights ``(D + 1,)``."""
    xb = np.hstack([x, np.ones((len(x), 1))])
    w = np.zeros(xb.shape[1])
    reg = l2 * np.eye(xb.shape[1])
    reg[-1, -1] = 0.0  # the intercept is not shrunk
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(xb @ w, -30, 30)))
        grad = xb.T @ (p - y) + reg @ w
        hess = (xb * (p * (1 - p))[:, None]).T @ xb + reg + 1e-9 * np.eye(xb.shape[1])
        step = np.linalg.solve(hess, grad)
        w -= step
        if np.abs(step).max() < 1e-8:
            break
    return w


def logistic_predict(w: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``(M,)`` predicted classes (0/1) of :func:`logistic_fit`'s weights on ``x`` ``(M, D)``."""
    return (np.hstack([x, np.ones((len(x), 1))]) @ w > 0).astype(np.int64)


class DomainProbe(Validator):
    """Domain separability: the held-out accuracy of a logistic regression trained fresh to tell
    source from target softmax maps (each map pooled to a ``grid x grid`` layout per class).

    Reference: the proxy A-distance of Ben-David et al. (2007, 2010), ``2 (1 - 2 err)`` from a
    domain classifier's held-out error; Musgrave et al. (2021) use a discriminator's accuracy.
    ``folds``-fold cross-validation (stratified, seeded) on equal numbers of source and target
    frames (the larger side subsampled). 0.5: the classifier cannot tell the domains apart; 1.0:
    it always can. Lower is better. Feed source maps with :meth:`update_source`."""

    name = "probe"
    higher_is_better = False

    def __init__(self, grid: int = 4, folds: int = 5, l2: float = 1e-2, seed: int = 0) -> None:
        if grid < 1 or folds < 2:
            raise UssSlamError(f"probe: expected grid >= 1 and folds >= 2, got {grid}, {folds}")
        self.grid, self.folds, self.l2, self.seed = grid, folds, l2, seed
        self.reset()

    def reset(self) -> None:
        self._target: list[np.ndarray] = []
        self._source: list[np.ndarray] = []

    def update(self, prob: np.ndarray) -> None:
        self._target.append(pooled_features(_check_prob(prob, self.name), self.grid))

    def update_source(self, prob: np.ndarray) -> None:
        self._source.append(pooled_features(_check_prob(prob, self.name), self.grid))

    def score(self) -> float:
        if not self._source or not self._target:
            return float("nan")
        src, trg = np.concatenate(self._source), np.concatenate(self._target)
        return probe_accuracy(src, trg, self.folds, self.l2, self.seed)


def probe_accuracy(src: np.ndarray, trg: np.ndarray, folds: int, l2: float, seed: int) -> float:
    """Cross-validated accuracy of :func:`logistic_fit` telling ``src`` ``(Ms, D)`` (label 0)
    from ``trg`` ``(Mt, D)`` (label 1); NaN with fewer than ``folds`` frames on a side."""
    rng = np.random.default_rng(seed)
    m = min(len(src), len(trg))
    if m < folds:
        return float("nan")
    src = src[rng.choice(len(src), m, replace=False)]
    trg = trg[rng.choice(len(trg), m, replace=False)]
    x = np.concatenate([src, trg])
    y = np.concatenate([np.zeros(m), np.ones(m)])
    fold = np.concatenate([rng.permutation(m) % folds, rng.permutation(m) % folds])
    correct = 0
    for k in range(folds):
        train, test = fold != k, fold == k
        mean, std = x[train].mean(axis=0), x[train].std(axis=0) + 1e-6
        w = logistic_fit((x[train] - mean) / std, y[train], l2)
        correct += int((logistic_predict(w, (x[test] - mean) / std) == y[test]).sum())
    return correct / len(x)


class DynamicShare(Validator):
    """The share of pixels whose most probable class is one of ``classes`` (model channel
    indices; default: channel 1, person), over every pixel of every frame. Descriptive
    (``higher_is_better`` None): a model that sees no person scores 0 on any target."""

    name = "dynamic_share"
    higher_is_better = None

    def __init__(self, classes: Sequence[int] = (1,)) -> None:
        self.classes = tuple(int(c) for c in classes)
        self.reset()

    def reset(self) -> None:
        self._hits, self._count = 0, 0

    def update(self, prob: np.ndarray) -> None:
        labels = _check_prob(prob, self.name).argmax(axis=1)
        self._hits += int(np.isin(labels, self.classes).sum())
        self._count += labels.size

    def score(self) -> float:
        return self._hits / self._count if self._count else float("nan")


VALIDATORS: dict[str, Callable[..., Validator]] = {
    "entropy": Entropy,
    "im": InformationMaximization,
    "snd": SoftNeighborhoodDensity,
    "probe": DomainProbe,
    "dynamic_share": DynamicShare,
}
"""Validator name -> class (keyword arguments from the ``validators`` config group)."""

NEEDS_SOURCE = frozenset({"probe"})
"""Validators that also need source softmax maps (:meth:`DomainProbe.update_source`)."""


def build_validators(
    names: Sequence[str],
    params: Mapping[str, Mapping[str, Any]] | None = None,
    where: str = "validators",
) -> dict[str, Validator]:
    """``{name: validator}`` for ``names`` with keyword arguments ``params[name]``; an unknown
    name or argument is one line naming ``where`` and what is accepted."""
    params = params or {}
    built: dict[str, Validator] = {}
    for name in names:
        if name not in VALIDATORS:
            raise UssSlamError(
                f"{where}: unknown validator {name!r}; expected some of {', '.join(VALIDATORS)}"
            )
        if name in built:
            raise UssSlamError(f"{where}: validator {name!r} given twice")
        kwargs = dict(params.get(name) or {})
        try:
            built[name] = VALIDATORS[name](**kwargs)
        except TypeError as error:
            raise UssSlamError(f"{where}.{name}: {error}") from None
    return built


@dataclass
class MaskAgreement:
    """Two models' dynamic-class masks over the same frames: ``iou`` pooled over all frames
    (intersection / union of pixels; 1.0 when both masks are empty everywhere), ``frame_iou``
    the per-frame IoUs, ``differ`` each frame's share of the image where the masks differ, and
    ``frames_differ`` the share of frames where that exceeds ``threshold`` (5% by default)."""

    iou: float
    frame_iou: np.ndarray
    differ: np.ndarray
    frames_differ: float
    threshold: float


class AgreementCounter:
    """Accumulates :class:`MaskAgreement` frame by frame: ``update(a, b)`` with two ``(H, W)``
    bool masks (or ``(N, H, W)`` batches)."""

    def __init__(self, threshold: float = 0.05) -> None:
        self.threshold = threshold
        self.inter, self.union = 0, 0
        self.frame_iou: list[float] = []
        self.differ: list[float] = []

    def update(self, a: np.ndarray, b: np.ndarray) -> None:
        a, b = np.asarray(a, bool), np.asarray(b, bool)
        if a.shape != b.shape:
            raise UssSlamError(f"mask agreement: masks of shapes {a.shape} and {b.shape}")
        if a.ndim == 2:
            a, b = a[None], b[None]
        for x, y in zip(a, b, strict=True):
            inter, union = int((x & y).sum()), int((x | y).sum())
            self.inter += inter
            self.union += union
            self.frame_iou.append(inter / union if union else 1.0)
            self.differ.append((union - inter) / x.size)

    def result(self) -> MaskAgreement:
        differ = np.array(self.differ)
        return MaskAgreement(
            iou=self.inter / self.union if self.union else 1.0,
            frame_iou=np.array(self.frame_iou),
            differ=differ,
            frames_differ=float((differ > self.threshold).mean()) if differ.size else float("nan"),
            threshold=self.threshold,
        )


def mask_agreement(a: np.ndarray, b: np.ndarray, threshold: float = 0.05) -> MaskAgreement:
    """:class:`MaskAgreement` of two ``(N, H, W)`` bool mask stacks (same frames, same order)."""
    counter = AgreementCounter(threshold)
    counter.update(a, b)
    return counter.result()

"""Descriptor matching: Hamming distances and guided (projection-window) matching, vectorised.

Guided matching is ORB-SLAM2's ``SearchByProjection``: every map point projected into the frame
looks for keypoints within a radius around its projection, on pyramid levels near the level its
distance predicts; the best descriptor distance wins if it is below ``max_distance`` and clearly
better than the second best (ratio test); each keypoint goes to at most one map point.
Candidates come from a uniform grid over the keypoints, so the cost grows with the number of
nearby pairs, not with (map points × keypoints).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distance of ``(P, 32)`` uint8 descriptor arrays -> ``(P,)`` int."""
    x = np.ascontiguousarray(a).view(np.uint64) ^ np.ascontiguousarray(b).view(np.uint64)
    return np.bitwise_count(x).sum(axis=1, dtype=np.int32)


def radius_pairs(
    query: np.ndarray,
    radius: np.ndarray,
    points: np.ndarray,
    size: tuple[int, int],
    cell: float = 16.0,
) -> tuple[np.ndarray, np.ndarray]:
    """All ``(query, point)`` index pairs closer than the query's radius.

    ``query`` (Q, 2) and ``points`` (N, 2) are pixel positions, ``radius`` (Q,) pixels, ``size``
    the image ``(width, height)`` used to lay out the grid (positions outside are clamped into
    the border cells, so nothing is lost).
    """
    qi, pi = cell_pairs(query, radius, points, size, cell)
    return within(qi, pi, query, radius, points)


def cell_pairs(
    query: np.ndarray,
    radius: np.ndarray,
    points: np.ndarray,
    size: tuple[int, int],
    cell: float = 16.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates of :func:`radius_pairs`: every ``(query, point)`` index pair whose point
    lies in a grid cell that the query's square of half-side ``radius`` touches, by query, then
    by cell row, then by point (what :func:`within` then tests)."""
    empty = np.zeros(0, np.int64)
    if len(query) == 0 or len(points) == 0:
        return empty, empty
    width, height = size
    nx, ny = max(1, math.ceil(width / cell)), max(1, math.ceil(height / cell))
    gx = _clamp((points[:, 0] // cell).astype(np.int64), nx - 1)
    gy = _clamp((points[:, 1] // cell).astype(np.int64), ny - 1)
    keys = gy * nx + gx
    order = np.argsort(keys, kind="stable")
    counts = np.bincount(keys, minlength=nx * ny)
    ends = np.cumsum(counts)
    starts = ends - counts  # cell c's points: order[starts[c] : ends[c]]

    x0 = _clamp(((query[:, 0] - radius) // cell).astype(np.int64), nx - 1)
    x1 = _clamp(((query[:, 0] + radius) // cell).astype(np.int64), nx - 1)
    y0 = _clamp(((query[:, 1] - radius) // cell).astype(np.int64), ny - 1)
    y1 = _clamp(((query[:, 1] + radius) // cell).astype(np.int64), ny - 1)
    # The cells x0..x1 of one grid row are consecutive keys, so their points are one run of
    # ``order``: one span per query and row, in the order of the query's cells.
    nrow = y1 - y0 + 1
    q_rep = np.repeat(np.arange(len(query)), nrow)
    row = y0[q_rep] + np.arange(len(q_rep)) - np.repeat(np.cumsum(nrow) - nrow, nrow)
    start = starts[row * nx + x0[q_rep]]
    count = ends[row * nx + x1[q_rep]] - start
    qi = np.repeat(q_rep, count)
    pi = order[np.arange(len(qi)) + np.repeat(start - (np.cumsum(count) - count), count)]
    return qi, pi


def within(
    qi: np.ndarray, pi: np.ndarray, query: np.ndarray, radius: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pairs ``(qi, pi)`` whose point lies within the query's radius (squared distances,
    ``dx² + dy² <= r²``), in their order."""
    dx = points[pi, 0] - query[qi, 0]
    dy = points[pi, 1] - query[qi, 1]
    r = radius[qi]
    keep = dx * dx + dy * dy <= r * r
    return qi[keep], pi[keep]


def _clamp(index: np.ndarray, top: int) -> np.ndarray:
    """``np.clip(index, 0, top)`` of an integer array, in place, without ``np.clip``'s Python
    wrapper (~5 µs a call, six calls per search)."""
    np.maximum(index, 0, out=index)
    return np.minimum(index, top, out=index)


@dataclass(frozen=True)
class Matches:
    """Accepted matches: ``query`` (M,) map-side indices, ``keypoint`` (M,) frame keypoint
    indices, ``distance`` (M,) Hamming distances."""

    query: np.ndarray
    keypoint: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.query)


def guided_match(
    proj: np.ndarray,
    radius: np.ndarray,
    level: np.ndarray,
    descriptors: tuple[np.ndarray, ...],
    kp_uv: np.ndarray,
    kp_octave: np.ndarray,
    kp_descriptors: np.ndarray,
    available: np.ndarray,
    size: tuple[int, int],
    *,
    max_distance: int = 100,
    ratio: float = 0.8,
    level_window: int = 1,
) -> Matches:
    """Match projected map points to keypoints.

    ``proj`` (Q, 2) projected positions, ``radius`` (Q,) search radii (px), ``level`` (Q,)
    predicted pyramid levels, ``descriptors`` one or more (Q, 32) descriptor sets per map point
    (the smallest distance over the sets counts), ``kp_uv`` (N, 2), ``kp_octave`` (N,),
    ``kp_descriptors`` (N, 32), ``available`` (N,) bool (keypoints that may be matched).
    """
    # The cheap tests first (keypoint free, level near the prediction), the distance on the
    # pairs that pass them: the same pairs, in the same order, as testing the distance first.
    qi, ki = cell_pairs(proj, radius, kp_uv, size)
    keep = available[ki] & (np.abs(kp_octave[ki] - level[qi]) <= level_window)
    qi, ki = within(qi[keep], ki[keep], proj, radius, kp_uv)
    empty = Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int32))
    if len(qi) == 0:
        return empty
    candidates = kp_descriptors[ki]
    dist = hamming(descriptors[0][qi], candidates)
    for extra in descriptors[1:]:
        dist = np.minimum(dist, hamming(extra[qi], candidates))
    order = _sort_by(qi, dist)
    qi, ki, dist = qi[order], ki[order], dist[order]
    best = np.flatnonzero(_starts(qi))
    has_second = np.diff(best, append=len(qi)) > 1
    second = np.where(has_second, dist[np.minimum(best + 1, len(qi) - 1)], _INT32_MAX)
    ok = (dist[best] <= max_distance) & (dist[best] < ratio * second)
    best = best[ok]
    if len(best) == 0:
        return empty
    qi, ki, dist = qi[best], ki[best], dist[best]
    # One map point per keypoint: the closest descriptor keeps it.
    order = _sort_by(ki, dist)
    sel = np.sort(order[_starts(ki[order])])
    return Matches(qi[sel], ki[sel], dist[sel])


_INT32_MAX = np.iinfo(np.int32).max


def _starts(sorted_keys: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: True where a run of equal values of the ``(n,)`` ``sorted_keys`` (n >= 1)
    starts."""
    first = np.empty(len(sorted_keys), bool)
    first[0] = True
    np.not_equal(sorted_keys[1:], sorted_keys[:-1], out=first[1:])
    return first


def _sort_by(key: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """``np.lexsort((dist, key))`` for non-negative indices ``key`` and Hamming distances
    ``dist`` (0..256): one stable sort of ``key * 512 + dist``, the same order (ties by
    position) for a tenth of NumPy's two-key lexsort's time on the thousands of candidate pairs
    of a frame (``key`` already in order for the first call, which the sort exploits)."""
    return np.argsort(key.astype(np.int64) * 512 + dist, kind="stable")

"""Model-comparison statistics: Musgrave's weighted Spearman against a plain re-statement, the
clustered bootstrap, and the frames a difference needs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import spearmanr

from uss_slam.core.verdict import (
    Interval,
    bootstrap_scores,
    cluster_draws,
    frames_needed,
    iou_from_matrix,
    separated,
    weighted_spearman,
)


def plain_weighted_spearman(scores, acc, power):
    """Written out: weights from the dense ranks of the scores; weighted ranks (smaller values'
    total weight + tie group's mean weight x (count + 1) / 2); weighted Pearson."""
    levels = sorted(set(scores))
    w = [((levels.index(s) + 1) / len(levels)) ** power for s in scores]

    def wrank(values):
        out = []
        for v in values:
            below = sum(wi for x, wi in zip(values, w, strict=True) if x < v)
            tie = [wi for x, wi in zip(values, w, strict=True) if x == v]
            out.append(below + (len(tie) + 1) / 2 * (sum(tie) / len(tie)))
        return out

    rx, ry = wrank(list(scores)), wrank(list(acc))
    total = sum(w)
    mx = sum(a * b for a, b in zip(w, rx, strict=True)) / total
    my = sum(a * b for a, b in zip(w, ry, strict=True)) / total
    cov = sum(wi * (a - mx) * (b - my) for wi, a, b in zip(w, rx, ry, strict=True))
    vx = sum(wi * (a - mx) ** 2 for wi, a in zip(w, rx, strict=True))
    vy = sum(wi * (b - my) ** 2 for wi, b in zip(w, ry, strict=True))
    return cov / math.sqrt(vx * vy)


def test_weighted_spearman_matches_restatement_with_ties():
    rng = np.random.default_rng(0)
    scores = np.round(rng.normal(size=25), 1)  # ties
    acc = scores + rng.normal(size=25)
    for power in (0.0, 1.0, 2.0):
        assert weighted_spearman(scores, acc, power) == pytest.approx(
            plain_weighted_spearman(scores.tolist(), acc.tolist(), power), rel=1e-9
        )


def test_weighted_spearman_power_zero_is_spearman_and_sign():
    rng = np.random.default_rng(1)
    s, a = rng.normal(size=30), rng.normal(size=30)
    assert weighted_spearman(s, a, 0.0) == pytest.approx(spearmanr(s, a).statistic)
    assert weighted_spearman(s, s * 2, 2.0) == pytest.approx(1.0)
    assert weighted_spearman(s, -s, 2.0) < -0.99  # weighted ranks: not exactly -1
    s_nan = s.copy()
    s_nan[0] = np.nan  # counts as the worst score
    s_low = s.copy()
    s_low[0] = s.min()
    assert weighted_spearman(s_nan, a) == weighted_spearman(s_low, a)


def frame_matrix(tp, fp, fn, tn):
    return np.array([[tn, fp], [fn, tp]])


def test_bootstrap_point_values_pair_and_interval():
    rng = np.random.default_rng(2)
    f = 40
    a = np.stack([frame_matrix(50, 10, 10, 900) for _ in range(f)])
    b = np.stack([frame_matrix(50 + int(rng.integers(5, 15)), 5, 5, 900) for _ in range(f)])
    r = bootstrap_scores(np.stack([a, b]), ["s"] * 20 + ["t"] * 20, cls=1, draws=300)
    assert r.iou[0].value == pytest.approx(iou_from_matrix(a.sum(0))[1])
    assert r.iou[0].low == pytest.approx(r.iou[0].value)  # identical frames: no spread
    d = r.diff_iou[(0, 1)]
    assert d.value == pytest.approx(r.iou[1].value - r.iou[0].value)
    assert d.excludes_zero() and d.low > 0
    assert frames_needed(d, f) == f  # already enough


def test_same_model_twice_gives_zero_difference_and_no_frame_count():
    a = np.stack([frame_matrix(10 + k, 3, 4, 100) for k in range(20)])
    r = bootstrap_scores(np.stack([a, a]), ["x"] * 20, cls=1, draws=100)
    assert r.diff_iou[(0, 1)].value == 0 and not r.diff_iou[(0, 1)].excludes_zero()
    assert frames_needed(r.diff_iou[(0, 1)], 20) is None


def test_frames_needed_scales_with_the_ratio():
    d = Interval(0.01, -0.01, 0.03, 0.01)  # se equal to the difference
    assert frames_needed(d, 20) == math.ceil(20 * 1.959963984540054**2)


def test_cluster_draws_keep_whole_sequences_in_play():
    clusters = ["a"] * 3 + ["b"] * 5
    draws = cluster_draws(clusters, 50, seed=0)
    for idx in draws:
        assert len(idx) in (6, 8, 10)  # two clusters drawn: 3+3, 3+5, 5+5 frames
    single = cluster_draws(["a"] * 4, 5, seed=0)
    assert all(len(i) == 4 and set(i) <= set(range(4)) for i in single)


def test_separated_only_without_overlap():
    assert separated((1, 2), (3, 4))
    assert not separated((1, 3), (3, 4))  # touching is overlap
    assert not separated((1, 5), (2, 3))

"""The label-free validators against plain re-statements of their references (loops over pixels,
the formulas of PyTorch Adapt's validators written out), and their edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.core.validators import (
    VALIDATORS,
    AgreementCounter,
    DomainProbe,
    DynamicShare,
    Entropy,
    InformationMaximization,
    SoftNeighborhoodDensity,
    build_validators,
    mask_agreement,
    probe_accuracy,
)


def softmax_maps(seed: int, n: int = 3, c: int = 4, h: int = 5, w: int = 6, sharp: float = 2.0):
    rng = np.random.default_rng(seed)
    logits = rng.normal(size=(n, c, h, w)) * sharp
    e = np.exp(logits - logits.max(axis=1, keepdims=True))
    return (e / e.sum(axis=1, keepdims=True)).astype(np.float32)


def pixels(prob):
    """Every pixel's probability vector, by plain loops."""
    return [prob[i, :, y, x].astype(float) for i in range(prob.shape[0])
            for y in range(prob.shape[2]) for x in range(prob.shape[3])]  # fmt: skip


def plain_entropy(p):
    return -sum(q * math.log(q) for q in p if q > 0)


def feed(validator, batches):
    for b in batches:
        validator.update(b)
    return validator.score()


def test_entropy_is_minus_mean_pixel_entropy_over_batches():
    a, b = softmax_maps(0), softmax_maps(1, n=2)
    expected = -np.mean([plain_entropy(p) for p in pixels(a) + pixels(b)])
    assert feed(Entropy(), [a, b]) == pytest.approx(expected, rel=1e-6)


def test_entropy_bounds_one_hot_and_uniform():
    one_hot = np.zeros((1, 4, 2, 2), np.float32)
    one_hot[:, 1] = 1
    assert feed(Entropy(), [one_hot]) == pytest.approx(0.0, abs=1e-9)
    uniform = np.full((1, 4, 2, 2), 0.25, np.float32)
    assert feed(Entropy(), [uniform]) == pytest.approx(-math.log(4), rel=1e-9)


def test_im_is_entropy_plus_diversity():
    a, b = softmax_maps(2), softmax_maps(3)
    rows = pixels(a) + pixels(b)
    mean = [sum(r[c] for r in rows) / len(rows) for c in range(4)]
    expected = -np.mean([plain_entropy(p) for p in rows]) + plain_entropy(mean)
    assert feed(InformationMaximization(), [a, b]) == pytest.approx(expected, rel=1e-6)


def test_im_prefers_diverse_confident_predictions():
    one_class = np.zeros((2, 4, 2, 2), np.float32)
    one_class[:, 0] = 1
    varied = np.zeros((2, 4, 2, 2), np.float32)
    for k in range(4):
        varied[:, k, k // 2, k % 2] = 1
    assert feed(InformationMaximization(), [varied]) > feed(InformationMaximization(), [one_class])


def plain_snd(samples, temperature):
    """SND written out: cosine similarity, self excluded, softmax / T, mean row entropy."""
    unit = [s / math.sqrt(sum(v * v for v in s)) for s in samples]
    total = 0.0
    for i, u in enumerate(unit):
        sims = [sum(a * b for a, b in zip(u, v, strict=True)) / temperature
                for j, v in enumerate(unit) if j != i]  # fmt: skip
        top = max(sims)
        e = [math.exp(s - top) for s in sims]
        total += plain_entropy([x / sum(e) for x in e])
    return total / len(unit)


def test_snd_with_every_pixel_sampled_matches_restatement():
    a = softmax_maps(4, n=2, h=3, w=3)
    v = SoftNeighborhoodDensity(pixels_per_image=9, temperature=0.05, block=4)
    assert feed(v, [a]) == pytest.approx(plain_snd(pixels(a), 0.05), rel=1e-6)


def test_snd_samples_per_image_and_is_seeded():
    a = softmax_maps(5, n=4, h=8, w=8)
    v1, v2 = (
        SoftNeighborhoodDensity(pixels_per_image=5, seed=3),
        SoftNeighborhoodDensity(pixels_per_image=5, seed=3),
    )
    assert feed(v1, [a]) == feed(v2, [a])
    assert sum(len(s) for s in v1._samples) == 4 * 5


def test_probe_tells_apart_shifted_domains_and_not_identical_ones():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(40, 8))
    assert probe_accuracy(src, rng.normal(size=(40, 8)) + 2.0, 5, 1e-2, 0) > 0.95
    same = probe_accuracy(src, rng.normal(size=(40, 8)), 5, 1e-2, 0)
    assert 0.2 < same < 0.8


def test_probe_on_maps_needs_source_and_balances_sides():
    trg = softmax_maps(6, n=20, sharp=1.0)
    src = softmax_maps(7, n=30, sharp=1.0)
    probe = DomainProbe(grid=2, folds=4)
    probe.update(trg)
    assert math.isnan(probe.score())  # no source maps yet
    probe.update_source(src)
    shifted = DomainProbe(grid=2, folds=4)
    shifted.update(trg)
    peaked = src.copy()
    peaked[:, 0] += 3.0
    shifted.update_source(peaked / peaked.sum(axis=1, keepdims=True))
    assert shifted.score() == 1.0
    assert probe.score() < 0.8
    assert DomainProbe.higher_is_better is False


def test_dynamic_share_counts_argmax_pixels():
    a = softmax_maps(8)
    expected = np.mean([int(np.argmax(p) in (1, 3)) for p in pixels(a)])
    assert feed(DynamicShare(classes=(1, 3)), [a]) == pytest.approx(expected)


def test_mask_agreement_pooled_iou_and_frames_that_differ():
    a = np.zeros((3, 10, 10), bool)
    b = np.zeros((3, 10, 10), bool)
    a[0, :5], b[0, :4] = True, True  # 10 of 100 pixels differ: > 5%
    a[1, :2], b[1, :2] = True, True  # identical
    b[2, 0, :3] = True  # 3% differ, a empty
    r = mask_agreement(a, b)
    assert r.iou == pytest.approx((40 + 20) / (50 + 20 + 3))
    assert r.frame_iou.tolist() == pytest.approx([0.8, 1.0, 0.0])
    assert r.differ.tolist() == pytest.approx([0.10, 0.0, 0.03])
    assert r.frames_differ == pytest.approx(1 / 3)
    counter = AgreementCounter()
    for x, y in zip(a, b, strict=True):
        counter.update(x, y)
    assert counter.result().iou == r.iou
    empty = mask_agreement(np.zeros((2, 3, 3), bool), np.zeros((2, 3, 3), bool))
    assert empty.iou == 1.0 and empty.frames_differ == 0.0


def test_build_validators_names_bad_config():
    built = build_validators(["entropy", "snd"], {"snd": {"pixels_per_image": 8}})
    assert set(built) == {"entropy", "snd"} and built["snd"].pixels_per_image == 8
    with pytest.raises(UssSlamError, match="unknown validator 'bogus'; expected some of entropy"):
        build_validators(["bogus"])
    with pytest.raises(UssSlamError, match=r"validators\.snd: .*unexpected keyword"):
        build_validators(["snd"], {"snd": {"k": 1}})
    with pytest.raises(UssSlamError, match="given twice"):
        build_validators(["im", "im"])


@pytest.mark.parametrize("name", sorted(VALIDATORS))
def test_bad_maps_are_one_line(name):
    with pytest.raises(UssSlamError, match=rf"{name}: expected \(N, C, H, W\) float"):
        VALIDATORS[name]().update(np.zeros((4, 5, 5), np.float32))


def test_scores_before_any_update_are_nan():
    for name, cls in VALIDATORS.items():
        assert math.isnan(cls().score()), name

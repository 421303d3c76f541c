"""Hamming distance, grid radius search and guided matching against brute-force references."""

from __future__ import annotations

import cv2
import numpy as np

from uss_slam.slam_eval.matching.descriptor import _sort_by, guided_match, hamming, radius_pairs


def test_hamming_matches_opencv() -> None:
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    expected = [cv2.norm(x, y, cv2.NORM_HAMMING) for x, y in zip(a, b, strict=True)]
    np.testing.assert_array_equal(hamming(a, b), expected)
    np.testing.assert_array_equal(hamming(a, a), 0)


def test_radius_pairs_equal_brute_force() -> None:
    rng = np.random.default_rng(1)
    points = rng.uniform(-20, 660, (400, 2))  # some outside the image: clamped, not lost
    query = rng.uniform(0, 640, (150, 2))
    radius = rng.uniform(1, 60, 150)
    qi, pi = radius_pairs(query, radius, points, (640, 480), cell=16.0)
    got = set(zip(qi.tolist(), pi.tolist(), strict=True))
    d2 = ((query[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
    expected = set(zip(*np.nonzero(d2 <= radius[:, None] ** 2), strict=True))
    assert got == {(int(a), int(b)) for a, b in expected}
    assert len(got) == len(qi)  # no duplicates
    # In a fixed order (guided matching's ties go by it): by query, then by grid cell row by
    # row, then by point index within a cell.
    gx = np.clip(points[:, 0] // 16, 0, 39).astype(int)
    gy = np.clip(points[:, 1] // 16, 0, 29).astype(int)
    pairs = list(zip(qi.tolist(), pi.tolist(), strict=True))
    assert pairs == sorted(pairs, key=lambda p: (p[0], gy[p[1]], gx[p[1]], p[1]))


def test_sort_by_is_the_two_key_lexsort() -> None:
    rng = np.random.default_rng(3)
    for n in (0, 1, 50, 3000):
        key = rng.integers(0, 40, n)
        dist = rng.integers(0, 257, n).astype(np.int32)  # 256: every bit differs
        np.testing.assert_array_equal(_sort_by(key, dist), np.lexsort((dist, key)))
        key.sort()  # the first call's keys come in order
        np.testing.assert_array_equal(_sort_by(key, dist), np.lexsort((dist, key)))


def test_guided_match_window_level_ratio_and_uniqueness() -> None:
    rng = np.random.default_rng(2)
    desc = rng.integers(0, 256, (6, 32), dtype=np.uint8)
    kp_uv = np.array([[100, 100], [103, 100], [200, 200], [300, 300], [400, 100], [50, 400]], float)
    kp_octave = np.array([0, 0, 0, 5, 0, 0])
    kp_desc = desc.copy()
    kp_desc[0, 0] ^= 0xFF  # keypoint 0 is 10 bits from point 0 ...
    kp_desc[0, 1] ^= 0x03
    kp_desc[1] = desc[0]
    kp_desc[1, 2] ^= 0xFF  # ... and keypoint 1, 3 px away, 12 bits: ambiguous
    kp_desc[1, 3] ^= 0x0F
    proj = kp_uv + 1.5
    level = np.zeros(6, int)
    radius = np.full(6, 5.0)
    m = guided_match(
        proj, radius, level, (desc,), kp_uv, kp_octave, kp_desc, np.ones(6, bool), (640, 480)
    )
    pairs = dict(zip(m.query.tolist(), m.keypoint.tolist(), strict=True))
    unmatched = {0, 1}  # 0: best 10, second 12 bits, fails the 0.8 ratio test; 1: its
    assert unmatched.isdisjoint(pairs)  # descriptor is ~128 bits from both nearby keypoints
    assert pairs == {2: 2, 4: 4, 5: 5}
    assert 3 not in pairs  # keypoint on level 5, predicted level 0: outside the level window
    # Without the competitor, point 0 matches keypoint 0 at distance 10.
    alone = np.ones(6, bool)
    alone[1] = False
    m1 = guided_match(proj, radius, level, (desc,), kp_uv, kp_octave, kp_desc, alone, (640, 480))
    assert dict(zip(m1.query.tolist(), m1.distance.tolist(), strict=True))[0] == 10
    # Unavailable keypoints are never matched; far projections find nothing.
    avail = np.ones(6, bool)
    avail[2] = False
    far = proj.copy()
    far[4] += 50
    m2 = guided_match(far, radius, level, (desc,), kp_uv, kp_octave, kp_desc, avail, (640, 480))
    assert 2 not in m2.query.tolist() and 4 not in m2.query.tolist()


def test_guided_match_gives_each_keypoint_to_the_closest_descriptor() -> None:
    rng = np.random.default_rng(3)
    kp_desc = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    near = kp_desc.copy()
    near[0, 0] ^= 0x01  # distance 1
    nearer = kp_desc.copy()  # distance 0
    desc = np.concatenate([near, nearer])
    m = guided_match(
        np.array([[10.0, 10.0], [11.0, 10.0]]),
        np.full(2, 5.0),
        np.zeros(2, int),
        (desc,),
        np.array([[10.0, 10.0]]),
        np.zeros(1, int),
        kp_desc,
        np.ones(1, bool),
        (64, 48),
    )
    assert m.query.tolist() == [1] and m.keypoint.tolist() == [0] and m.distance.tolist() == [0]


def test_guided_match_uses_the_best_of_several_descriptor_sets() -> None:
    rng = np.random.default_rng(4)
    kp_desc = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    old = rng.integers(0, 256, (1, 32), dtype=np.uint8)  # ~128 bits away: no match
    args = (np.array([[5.0, 5.0]]), np.full(1, 3.0), np.zeros(1, int))
    rest = (np.array([[5.0, 5.0]]), np.zeros(1, int), kp_desc, np.ones(1, bool), (32, 32))
    assert len(guided_match(*args, (old,), *rest)) == 0
    m = guided_match(*args, (old, kp_desc), *rest)
    assert len(m) == 1 and m.distance[0] == 0


def test_guided_match_equals_testing_the_distance_first() -> None:
    """The window, level and availability tests in another order than guided matching runs
    them (the radius search first, as it used to): the same matches, distances and order."""
    rng = np.random.default_rng(5)
    for trial in range(20):
        q, n = int(rng.integers(0, 120)), int(rng.integers(1, 300))
        proj = rng.uniform(-10, 650, (q, 2))
        radius = rng.uniform(1, 40, q)
        level = rng.integers(0, 8, q)
        sets = tuple(rng.integers(0, 256, (q, 32), dtype=np.uint8) for _ in range(1 + trial % 2))
        kp_uv = rng.uniform(0, 640, (n, 2))
        kp_octave = rng.integers(0, 8, n)
        kp_desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
        kp_desc[: n // 2] = sets[0][rng.integers(0, max(q, 1), n // 2)] if q else kp_desc[: n // 2]
        kp_desc[: n // 2, 0] ^= rng.integers(0, 256, n // 2, dtype=np.uint8)  # near copies
        available = rng.random(n) < 0.8
        got = guided_match(
            proj, radius, level, sets, kp_uv, kp_octave, kp_desc, available, (640, 480)
        )
        qi, ki = radius_pairs(proj, radius, kp_uv, (640, 480))
        keep = available[ki] & (np.abs(kp_octave[ki] - level[qi]) <= 1)
        qi, ki = qi[keep], ki[keep]
        dist = np.min([hamming(s[qi], kp_desc[ki]) for s in sets], axis=0) if len(qi) else qi
        best: dict[int, tuple[int, int]] = {}  # query -> (distance, keypoint), first smallest
        second: dict[int, int] = {}
        for a, b, d in zip(qi.tolist(), ki.tolist(), np.asarray(dist).tolist(), strict=True):
            if a not in best or d < best[a][0]:
                if a in best:
                    second[a] = best[a][0]
                best[a] = (d, b)
            else:
                second[a] = min(second.get(a, 1 << 30), d)
        accepted = {
            a: (d, b)
            for a, (d, b) in best.items()
            if d <= 100 and d < 0.8 * second.get(a, np.iinfo(np.int32).max)
        }
        owner: dict[int, tuple[int, int]] = {}  # keypoint -> (distance, query), closest first
        for a, (d, b) in sorted(accepted.items()):
            if b not in owner or d < owner[b][0]:
                owner[b] = (d, a)
        expected = sorted((a, b, d) for b, (d, a) in owner.items())
        order = sorted(range(len(got)), key=lambda i: got.keypoint[i])
        assert [int(got.keypoint[i]) for i in order] == sorted(b for _, b, _ in expected)
        assert sorted(zip(got.query.tolist(), got.keypoint.tolist(), got.distance.tolist(),
                          strict=True)) == expected  # fmt: skip

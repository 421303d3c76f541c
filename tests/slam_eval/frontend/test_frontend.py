"""ORB front end: ORB-SLAM2's per-level budget, grid spread, FAST fallback, depth, undistortion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.frontend.orb import EDGE, OrbConfig, OrbExtractor

CAM = TUM_CAMERAS["fr3"]


def test_level_budgets_follow_orb_slam2() -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    assert sum(ex.budgets) == 1000
    # ORB-SLAM2: n * (1 - 1/s) / (1 - (1/s)^L) on level 0, then a factor 1/s per level.
    assert ex.budgets[:3] == [217, 181, 151]
    np.testing.assert_allclose(ex.scales, 1.2 ** np.arange(8))


def test_extracts_the_budget_spread_over_the_image(texture) -> None:
    gray = texture((640, 480))
    ex = OrbExtractor(OrbConfig(), CAM)
    f = ex(gray, None)
    assert len(f) == 1000
    assert np.bincount(f.octave, minlength=8).tolist() == ex.budgets
    assert f.descriptors.shape == (1000, 32) and f.descriptors.dtype == np.uint8

    # Grid bucketing: level-0 keypoints occupy far more 64x64 cells than OpenCV's own ORB,
    # which keeps the strongest corners wherever they are.
    def cells(xy: np.ndarray) -> int:
        return len(np.unique((xy // 64).astype(int), axis=0))

    ours = cells(f.xy[f.octave == 0])
    orb = cv2.ORB_create(1000, 1.2, 8, 19, 0, 2, cv2.ORB_HARRIS_SCORE, 31, 20)
    kps = orb.detect(gray, None)
    theirs = cells(np.array([k.pt for k in kps if k.octave == 0]))
    assert ours >= 70  # of 80 cells
    assert ours > theirs
    # Keypoints keep ORB-SLAM2's border.
    for level in range(8):
        xy = f.xy[f.octave == level] / ex.scales[level]
        assert xy.min() >= EDGE - 1e-3


def test_low_threshold_fills_cells_without_strong_corners(texture) -> None:
    gray = texture((320, 240), seed=1)
    # A faint texture on the left half: FAST 20 finds nothing there, FAST 7 does.
    left = gray[:, :160].astype(np.float32)
    gray[:, :160] = np.clip(128 + (left - left.mean()) * 0.08, 0, 255).astype(np.uint8)
    strong = cv2.FastFeatureDetector_create(20, True).detect(gray[:, :150])
    assert len(strong) == 0
    cam = CAM.scaled(320, 240)
    with_fallback = OrbExtractor(OrbConfig(min_fast=7), cam)(gray, None)
    without = OrbExtractor(OrbConfig(min_fast=20), cam)(gray, None)
    assert (with_fallback.xy[:, 0] < 150).sum() > 50
    assert (without.xy[:, 0] < 150).sum() == 0


def test_low_threshold_search_equals_one_fast_call_per_empty_cell(texture) -> None:
    """The fallback search finds exactly FAST 20's corners plus the corners FAST 7 finds in each
    horizontal run of empty cells searched alone (with its 3 px ring)."""
    gray = texture((320, 240), seed=6)
    left = gray[:, :160].astype(np.float32)
    gray[:, :160] = np.clip(128 + (left - left.mean()) * 0.08, 0, 255).astype(np.uint8)
    ex = OrbExtractor(OrbConfig(), CAM.scaled(320, 240))
    xy, score = ex._detect_level(gray, 10**6)  # a budget this large keeps every corner

    def corners(threshold: int, x0: int, y0: int, x1: int, y1: int) -> set[tuple]:
        fast = cv2.FastFeatureDetector_create(threshold, True)
        found = fast.detect(gray[y0 - 3 : y1 + 3, x0 - 3 : x1 + 3])
        return {
            (k.pt[0] + x0 - 3, k.pt[1] + y0 - 3, k.response)
            for k in found
            if x0 <= k.pt[0] + x0 - 3 < x1 and y0 <= k.pt[1] + y0 - 3 < y1
        }

    h, w = gray.shape
    lo, hi_x, hi_y, cell = EDGE, w - EDGE, h - EDGE, 30
    expected = corners(20, lo, lo, hi_x, hi_y)
    strong = {(int((x - lo) // cell), int((y - lo) // cell)) for x, y, _ in expected}
    empty = 0
    for y0 in range(lo, hi_y, cell):
        row = [
            x0
            for x0 in range(lo, hi_x, cell)
            if ((x0 - lo) // cell, (y0 - lo) // cell) not in strong
        ]
        empty += len(row)
        while row:  # one search per horizontal run of empty cells
            run = [row.pop(0)]
            while row and row[0] == run[-1] + cell:
                run.append(row.pop(0))
            y1 = min(y0 + cell, hi_y)
            expected |= corners(7, run[0], y0, min(run[-1] + cell, hi_x), y1)
    assert empty > 10
    got = {(float(x), float(y), float(r)) for (x, y), r in zip(xy, score, strict=True)}
    assert len(got) == len(xy) and got == expected


def test_bucketing_takes_each_cells_best_corners_rank_by_rank(texture) -> None:
    """With more corners than the budget: every cell's best corner first (better scores first,
    then cell order), then every cell's second best, ... exactly in that order."""
    gray = texture((320, 240), seed=8)
    ex = OrbExtractor(OrbConfig(), CAM.scaled(320, 240))
    everything, scores = ex._detect_level(gray, 10**6)
    budget = 150
    xy, score = ex._detect_level(gray, budget)
    h, w = gray.shape
    span_x, span_y = w - 2 * EDGE, h - 2 * EDGE
    side = np.sqrt(span_x * span_y / budget)
    bx = int(np.ceil(span_x / side))
    cells = [
        int((y - EDGE) / side) * bx + min(int((x - EDGE) / side), bx - 1) for x, y in everything
    ]
    by_cell: dict[int, list[int]] = {}
    for i in sorted(range(len(cells)), key=lambda i: (cells[i], -scores[i], i)):
        by_cell.setdefault(cells[i], []).append(i)
    rank = {i: r for members in by_cell.values() for r, i in enumerate(members)}
    expected = sorted(range(len(cells)), key=lambda i: (rank[i], -scores[i], cells[i], i))[:budget]
    assert len(everything) > 2 * budget
    np.testing.assert_array_equal(xy, everything[expected])
    np.testing.assert_array_equal(score, scores[expected])


def test_orientation_is_the_exact_disc_centroid(texture) -> None:
    gray = texture((320, 240), seed=7)
    ex = OrbExtractor(OrbConfig(), CAM.scaled(320, 240))
    xy, _ = ex._detect_level(gray, 300)
    dy, dx = np.mgrid[-15:16, -15:16]
    disc = dx**2 + dy**2 <= 15**2 + 15
    expected = []
    for x, y in np.rint(xy).astype(int):
        patch = gray[y - 15 : y + 16, x - 15 : x + 16].astype(np.int64)
        m01, m10 = np.float32((patch * dy)[disc].sum()), np.float32((patch * dx)[disc].sum())
        expected.append(np.degrees(np.arctan2(m01, m10)) % 360.0)
    np.testing.assert_array_equal(ex._orientation(gray, xy), np.array(expected, np.float32))


def test_orientation_matches_opencv_orb(texture) -> None:
    gray = texture((640, 480), seed=2)
    orb = cv2.ORB_create(500, 1.2, 1, 19, 0, 2, cv2.ORB_FAST_SCORE, 31, 20)
    kps = orb.detect(gray, None)
    ex = OrbExtractor(OrbConfig(), CAM)
    xy = np.array([k.pt for k in kps], np.float32)
    ours = ex._orientation(gray, xy)
    theirs = np.array([k.angle for k in kps])
    diff = np.abs((ours - theirs + 180) % 360 - 180)
    assert np.median(diff) < 0.5 and np.percentile(diff, 95) < 3.0


def test_depth_lookup_and_backprojection(texture) -> None:
    gray = texture((320, 240), seed=3)
    cam = CAM.scaled(320, 240)
    depth = np.full((240, 320), 2.0, np.float32)
    depth[:, 200:] = 0.0  # no measurement
    depth[:120, :100] = 9.0  # beyond max_depth
    f = OrbExtractor(OrbConfig(max_depth=4.0), cam)(gray, depth)
    x, y = np.rint(f.xy[:, 0]), np.rint(f.xy[:, 1])
    valid = (x < 200) & ~((y < 120) & (x < 100))
    np.testing.assert_array_equal(f.has_depth, valid)
    np.testing.assert_array_equal(f.depth[valid], 2.0)
    assert np.isnan(f.points[~valid]).all()
    expected_x = (f.uv[valid, 0] - cam.cx) * 2.0 / cam.fx
    expected_y = (f.uv[valid, 1] - cam.cy) * 2.0 / cam.fy
    np.testing.assert_allclose(f.points[valid, 0], expected_x)
    np.testing.assert_allclose(f.points[valid, 1], expected_y)
    np.testing.assert_array_equal(f.points[valid, 2], 2.0)


def test_distortion_handled_for_keypoints(texture) -> None:
    fr1 = TUM_CAMERAS["fr1"]
    ex = OrbExtractor(OrbConfig(), fr1)
    xy = np.array([[10.0, 12.0], [320.0, 240.0], [600.0, 450.0]])
    uv = ex.undistort(xy)
    ref = cv2.undistortPoints(
        xy.reshape(-1, 1, 2), fr1.matrix, np.array(fr1.distortion), P=fr1.matrix
    ).reshape(-1, 2)
    np.testing.assert_allclose(uv, ref)
    assert np.abs(uv[0] - xy[0]).max() > 5  # corners move noticeably with fr1's distortion
    # Re-distorting gives the original pixels back.
    rays = np.column_stack([(uv[:, 0] - fr1.cx) / fr1.fx, (uv[:, 1] - fr1.cy) / fr1.fy, np.ones(3)])
    back = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), fr1.matrix, np.array(fr1.distortion))[
        0
    ]
    np.testing.assert_allclose(back.reshape(-1, 2), xy, atol=0.05)
    f = ex(texture((640, 480), seed=4), None)
    np.testing.assert_allclose(f.uv, ex.undistort(f.xy))


def test_deterministic_and_empty_image(texture) -> None:
    gray = texture((320, 240), seed=5)
    ex = OrbExtractor(OrbConfig(), CAM.scaled(320, 240))
    a, b = ex(gray, None), ex(gray, None)
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.descriptors, b.descriptors)
    flat = ex(np.full((240, 320), 128, np.uint8), None)
    assert len(flat) == 0 and flat.descriptors.shape == (0, 32)


def test_config_validation() -> None:
    with pytest.raises(ValueError, match=r"scale_factor: expected a number > 1.0, got 1.0"):
        OrbConfig(scale_factor=1.0)
    with pytest.raises(ValueError, match=r"min_fast: expected an integer <= ini_fast \(5\), got 7"):
        OrbConfig(ini_fast=5, min_fast=7)
    with pytest.raises(
        ValueError, match=r"min_depth: expected a number < max_depth \(4.0\), got 5.0"
    ):
        OrbConfig(min_depth=5.0, max_depth=4.0)


def test_descriptors_are_opencvs_on_the_keypoints_built_one_by_one(texture) -> None:
    """The keypoints handed to OpenCV's rBRIEF (built without a Python frame each) are those
    built one by one: the same descriptors, rows in keypoint order."""
    gray = texture((640, 480), seed=9)
    ex = OrbExtractor(OrbConfig(), CAM)
    features = ex(gray, None)
    xy, octave, angle, response = ex.detect(gray)
    sizes = 31 * ex.scales[octave]
    keypoints = [
        cv2.KeyPoint(float(x), float(y), float(s), float(a), float(r), int(o), k)
        for k, ((x, y), s, a, r, o) in enumerate(
            zip(xy, sizes, angle, response, octave, strict=True)
        )
    ]
    described, descriptors = ex._orb.compute(gray, keypoints)
    order = np.argsort([k.class_id for k in described], kind="stable")
    np.testing.assert_array_equal(features.descriptors, descriptors[order])
    kept = np.sort([k.class_id for k in described])
    np.testing.assert_array_equal(features.xy, xy[kept])
    np.testing.assert_array_equal(features.response, response[kept])

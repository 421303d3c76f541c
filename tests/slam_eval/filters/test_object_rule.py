"""The object rule (robust semantic mapping, Algorithm 1) on a constructed frame: step 1 takes
whole objects with more than Num flagged keypoints, step 2 the pixels near the other flagged
keypoints (σ1 = 0.1 m in depth, σ2 = 5 px in the image)."""

from __future__ import annotations

import numpy as np
import pytest
from filter_helpers import CAM, features_at
from omegaconf import OmegaConf

from uss_slam.core.errors import UssSlamError
from uss_slam.core.schema import check_target
from uss_slam.slam_eval.config import filter_defaults
from uss_slam.slam_eval.filters.base import FilterContext
from uss_slam.slam_eval.filters.object_rule import ObjectFilter
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.sequence import Frame


def _context(xy: np.ndarray, motion: np.ndarray, labels: np.ndarray, depth: np.ndarray):
    ex = OrbExtractor(OrbConfig(), CAM)
    features = features_at(ex, xy, depth)
    gray = np.zeros(depth.shape, np.uint8)
    frame = Frame(0, 0.0, np.repeat(gray[:, :, None], 3, axis=2), gray, depth, labels)
    return FilterContext(frame, features, labels, ex, None, motion_flags=motion)  # type: ignore[arg-type]


def _scene():
    """A dragged chair (object A, 25 flagged keypoints), a still chair (object B, 3 flagged),
    and a flagged keypoint on the background wall (3 m) next to a pillar edge (1.5 m)."""
    labels = np.zeros((240, 320), np.uint8)
    labels[20:100, 20:100] = 2  # chair A
    labels[20:100, 200:280] = 2  # chair B
    depth = np.full((240, 320), 3.0, np.float32)
    depth[20:100, 20:100] = 2.0
    depth[20:100, 200:280] = 2.2
    depth[152:240, 163:200] = 1.5  # pillar, 2 px below and 3 px right of the wall point (160, 150)
    depth[147:149, 157:159] = 0.0  # no depth: never dynamic
    depth[153, 158] = 3.09  # within 0.1 m of the wall point's 3.0 m
    depth[153, 162] = 3.11  # not within 0.1 m
    xs, ys = np.meshgrid(np.arange(25, 95, 12), np.arange(25, 95, 12))
    a = np.column_stack([xs.ravel(), ys.ravel()])[:30]
    b = a + [180, 0]
    wall = np.array([[160, 150]])
    probes = np.array(
        [
            [163, 150],  # 3 px right, wall depth: dynamic
            [160, 154],  # 4 px below: dynamic
            [160, 155],  # 5 px below: not closer than σ2
            [163, 153],  # 3 px right, 3 px below: on the pillar (1.5 m), not dynamic
            [170, 150],  # 10 px away
            [300, 220],  # far away
        ]
    )
    xy = np.concatenate([a, b, wall, probes]).astype(np.float64)
    motion = np.zeros(len(xy), bool)
    motion[:25] = True
    motion[30:33] = True
    motion[60] = True  # the wall keypoint
    return xy, motion, labels, depth


def test_step_one_takes_whole_objects_and_step_two_the_pixels_near_other_dynamic_points() -> None:
    xy, motion, labels, depth = _scene()
    out = ObjectFilter()(_context(xy, motion, labels, depth))
    assert out.dynamic[:30].all()  # chair A as a whole
    # Chair B's 3 flagged keypoints stay (they are flagged already); step 2 grows around them on
    # the chair's own depth, which holds no other keypoint.
    assert out.dynamic[30:33].all() and not out.dynamic[33:60].any()
    assert out.dynamic[60:].tolist() == [True, True, True, False, False, False, False]
    region = out.region
    assert region is not None
    assert region[20:100, 20:100].all()
    # Around the wall point (160, 150): the disc of radius 5 (exclusive), minus other depths.
    expected = np.zeros((240, 320), bool)
    yy, xx = np.mgrid[0:240, 0:320]
    disc = (xx - 160) ** 2 + (yy - 150) ** 2 < 25
    expected |= disc & (np.abs(depth - 3.0) < 0.1) & (depth > 0)
    for x, y in xy[30:33]:
        expected |= ((xx - x) ** 2 + (yy - y) ** 2 < 25) & (np.abs(depth - 2.2) < 0.1)
    expected[20:100, 20:100] = True
    np.testing.assert_array_equal(region, expected)
    assert region[153, 158] and not region[153, 162]  # 3.09 m in, 3.11 m out
    assert not region[147:149, 157:159].any()  # no depth
    assert region[150, 163] and not region[152:155, 163:165].any()  # wall in, pillar out


def test_step_two_can_be_switched_off_and_needs_depth() -> None:
    xy, motion, labels, depth = _scene()
    ctx = _context(xy, motion, labels, depth)
    off = ObjectFilter(pixel_radius=0)(ctx)
    assert off.dynamic[:30].all() and not off.dynamic[30:].any()
    assert off.region is not None and off.region.sum() == 80 * 80
    # Without any object over Num, step 2 still applies (Algorithm 1, line 7).
    alone = ObjectFilter(min_points=40)(ctx)
    assert alone.dynamic[:25].all() and not alone.dynamic[25:30].any()
    assert alone.dynamic[61] and not alone.dynamic[64]
    # A flagged keypoint without depth contributes nothing.
    flat = np.zeros_like(depth)
    none = ObjectFilter(min_points=40)(_context(xy, motion, labels, flat))
    assert not none.dynamic.any() and none.region is None


def test_object_rule_parameters() -> None:
    assert filter_defaults()["object"] == {
        "min_points": 20,
        "classes": None,
        "depth_radius": 0.1,
        "pixel_radius": 5.0,
    }
    # the ranges are the config's schema (slam.filter_params.object.*)
    node = OmegaConf.create({"_target_": "uss_slam.slam_eval.filters.object_rule.ObjectFilter"})
    for key, value, line in (
        ("depth_radius", 0, "slam.filter_params.object.depth_radius: expected a number > 0, got 0"),
        ("pixel_radius", -1, "slam.filter_params.object.pixel_radius: expected a number >= 0, "
                             "got -1"),
    ):  # fmt: skip
        bad = OmegaConf.merge(node, {key: value})
        with pytest.raises(UssSlamError) as info:
            check_target(bad, "slam.filter_params.object")
        assert str(info.value) == line

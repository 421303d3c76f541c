"""Dynamic filters on crafted cases: what moved is flagged, what stayed is not."""

from __future__ import annotations

import numpy as np
import pytest
from filter_helpers import CAM, features_at

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.config import filter_defaults
from uss_slam.slam_eval.filters.base import FilterContext
from uss_slam.slam_eval.filters.build import build_filters, shipped_filter_configs
from uss_slam.slam_eval.filters.flow import FlowFilter
from uss_slam.slam_eval.filters.geometry import GeometryFilter
from uss_slam.slam_eval.filters.object_rule import ObjectFilter
from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.map.slam_map import SlamMap
from uss_slam.slam_eval.sequence import Frame


def _frame(index: int, gray: np.ndarray, depth: np.ndarray, labels=None) -> Frame:
    rgb = np.repeat(gray[:, :, None], 3, axis=2)
    return Frame(index, index / 30.0, rgb, gray, depth, labels)


def _grid(x0: int, x1: int, y0: int, y1: int, step: int) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float32)


# ------------------------------------------------------------------------------ semantic


def test_semantic_drops_dilated_person_mask_only() -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    labels = np.zeros((240, 320), np.uint8)
    labels[100:140, 100:140] = 1  # person
    labels[20:60, 200:260] = 2  # chair: not a dynamic class
    xy = np.array([[120, 120], [143, 120], [147, 120], [160, 120], [230, 40], [10, 10]], float)
    ctx = FilterContext(
        _frame(0, np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.float32), labels),
        features_at(ex, xy, np.zeros((240, 320), np.float32)),
        labels,
        ex,
        None,  # type: ignore[arg-type]
    )
    out = SemanticFilter(dynamic_classes=["person"], dilation=5)(ctx)
    # inside; 4 px outside (within the 5 px dilation); 8 px and 21 px outside; chair; background
    assert out.dynamic.tolist() == [True, True, False, False, False, False]
    assert out.region is not None and out.region[100:140, 100:140].all()
    assert SemanticFilter(dilation=0)(ctx).dynamic.tolist()[:3] == [True, False, False]
    both = SemanticFilter(dynamic_classes=["person", "chair"], dilation=0)(ctx)
    assert both.dynamic.tolist() == [True, False, False, False, True, False]
    ctx.labels = None
    with pytest.raises(UssSlamError, match="filter semantic needs a segmenter"):
        SemanticFilter()(ctx)


# ------------------------------------------------------------------------------ flow


def test_flow_flags_the_moving_patch_not_the_ego_motion(texture) -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    z = 2.0
    canvas = texture((400, 240), seed=7)
    patch = texture((60, 60), seed=8)
    shift = 8  # camera moves right: the static scene moves 8 px left
    prev = canvas[:, 20:340].copy()
    cur = canvas[:, 20 + shift : 340 + shift].copy()
    prev[90:150, 120:180] = patch
    cur[90:150, 132:192] = patch  # the object moved 12 px right in the image
    depth = np.full((240, 320), z, np.float32)
    features = ex(cur, depth)
    ctx = FilterContext(
        _frame(1, cur, depth),
        features,
        None,
        ex,
        None,
        previous=_frame(0, prev, depth),  # type: ignore[arg-type]
    )
    out = FlowFilter(threshold=7.0)(ctx)
    x, y = features.xy[:, 0], features.xy[:, 1]
    on_object = (x >= 144) & (x < 180) & (y >= 102) & (y < 138)  # 12 px inside the patch
    static = ~((x >= 100) & (x < 215) & (y >= 70) & (y < 170))  # well away from the object
    assert on_object.sum() >= 15 and static.sum() >= 200
    assert out.dynamic[on_object].mean() > 0.8
    assert out.dynamic[static].mean() < 0.02
    assert 0.95 * features.has_depth.sum() <= out.checked <= features.has_depth.sum()
    # Without a previous frame nothing can be judged.
    ctx.previous = None
    first = FlowFilter()(ctx)
    assert not first.dynamic.any() and first.checked == 0


# ------------------------------------------------------------------------------ geometry


def _geometry_case(ex: OrbExtractor):
    """A keyframe saw a wall at 3 m and a box at 2 m; now a person stands at 1.5 m in front."""
    slam_map = SlamMap(ex.config.scale_factor, ex.config.n_levels)
    wall = np.full((240, 320), 3.0, np.float32)
    kf_depth = wall.copy()
    kf_depth[150:220, 20:100] = 2.0  # box
    kf_xy = _grid(10, 310, 10, 230, 6)
    kf = features_at(ex, kf_xy, kf_depth)
    keyframe = slam_map.add_keyframe(0, 0.0, np.eye(4), kf, np.full(len(kf), -1),
                                        np.zeros(len(kf), bool), kf.has_depth)  # fmt: skip
    keyframe.depth = kf_depth[:: keyframe.depth_stride, :: keyframe.depth_stride]
    pose_wc = np.eye(4)
    pose_wc[0, 3] = 0.05  # the camera moved 5 cm to the right
    # The wall (a plane facing the camera) keeps its depth; the nearer box shifts by
    # fx * 0.05 / 2 = 6.7 px to the left, uncovering wall on its right and hiding wall on its left.
    depth = wall.copy()
    depth[150:220, 13:93] = 2.0
    depth[60:180, 150:230] = 1.5  # the person
    xy = _grid(12, 308, 12, 228, 8)
    features = features_at(ex, xy, depth)
    ctx = FilterContext(
        _frame(20, np.zeros((240, 320), np.uint8), depth),
        features,
        None,
        ex,
        slam_map,
        pose_wc=pose_wc,
        matched=np.full(len(features), -1),
    )
    return ctx, xy


def test_geometry_flags_what_appeared_in_front_of_the_static_scene() -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    ctx, xy = _geometry_case(ex)
    out = GeometryFilter()(ctx)
    x, y = xy[:, 0], xy[:, 1]
    person = (x >= 150) & (x < 230) & (y >= 60) & (y < 180)
    box = (x >= 13) & (x < 93) & (y >= 150) & (y < 220)
    assert person.sum() > 50 and box.sum() > 30
    assert out.dynamic[person].all()  # seeds grown over the whole person region
    assert not out.dynamic[box].any()  # static object, also seen by the keyframe
    assert not out.dynamic[~person].any()
    assert out.region is not None and out.region[70:170, 160:220].all()


def test_geometry_respects_parallax_age_and_seed_count() -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    ctx, _ = _geometry_case(ex)
    # The 5 cm move makes parallax angles of about 1 degree: a 0.5 degree limit ignores them all.
    assert not GeometryFilter(max_parallax_deg=0.5)(ctx).dynamic.any()
    # The keyframe is 20 frames old; requiring 30 leaves no reference keyframe.
    assert not GeometryFilter(min_keyframe_age=30)(ctx).dynamic.any()
    # A single seed is not enough when min_seeds is large.
    assert not GeometryFilter(min_seeds=10_000)(ctx).dynamic.any()
    # Without a pose the filter cannot run.
    ctx.pose_wc = None
    assert not GeometryFilter()(ctx).dynamic.any()


def test_geometry_reverse_check_spares_static_occluders() -> None:
    """The camera moves 20 cm: a pillar 1 m away now hides wall points 3 m away that the
    keyframe saw beside it, deep inside the pillar's silhouette. The keyframe saw the pillar
    too, so projecting the seed back into the keyframe explains it: no dynamic region."""
    ex = OrbExtractor(OrbConfig(), CAM)
    slam_map = SlamMap(ex.config.scale_factor, ex.config.n_levels)
    kf_depth = np.full((240, 320), 3.0, np.float32)
    kf_depth[:, 100:140] = 1.0  # pillar
    kf_feats = features_at(ex, _grid(10, 310, 10, 230, 6), kf_depth)
    kf = slam_map.add_keyframe(0, 0.0, np.eye(4), kf_feats, np.full(len(kf_feats), -1),
                                  np.zeros(len(kf_feats), bool), kf_feats.has_depth)  # fmt: skip
    pose_wc = np.eye(4)
    pose_wc[0, 3] = 0.2
    depth = np.full((240, 320), 3.0, np.float32)
    depth[:, 47:87] = 1.0  # the pillar moved 53.5 px left in the image, the wall 17.8 px
    xy = _grid(12, 308, 12, 228, 8)
    ctx = FilterContext(
        _frame(20, np.zeros((240, 320), np.uint8), depth),
        features_at(ex, xy, depth),
        None,
        ex,
        slam_map,
        pose_wc=pose_wc,
        matched=np.full(len(xy), -1),
    )
    geometry = GeometryFilter()
    assert len(geometry.seeds(ctx)) > 20  # without the keyframe's depth: many seeds
    assert GeometryFilter()(ctx).dynamic.sum() > 20
    kf.depth = kf_depth[:: kf.depth_stride, :: kf.depth_stride]
    assert len(geometry.seeds(ctx)) == 0
    assert not geometry(ctx).dynamic.any()


# ------------------------------------------------------------------------------ object rule


def test_object_rule_spreads_motion_flags_over_the_whole_object() -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    labels = np.zeros((240, 320), np.uint8)
    labels[20:100, 20:100] = 2  # chair A (being dragged)
    labels[20:100, 200:280] = 2  # chair B (still)
    a = _grid(25, 95, 25, 95, 12)[:30]
    b = _grid(205, 275, 25, 95, 12)[:30]
    bg = _grid(20, 300, 150, 230, 20)[:20]
    xy = np.concatenate([a, b, bg])
    features = features_at(ex, xy, np.zeros((240, 320), np.float32))
    motion = np.zeros(len(xy), bool)
    motion[:25] = True  # 25 of A's keypoints moved
    motion[30:33] = True  # 3 of B's: noise
    ctx = FilterContext(
        _frame(0, np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.float32), labels),
        features,
        labels,
        ex,
        None,  # type: ignore[arg-type]
        motion_flags=motion,
    )
    out = ObjectFilter(min_points=20)(ctx)
    assert out.dynamic[:30].all() and not out.dynamic[30:].any()
    assert out.region is not None and out.region[20:100, 20:100].all()
    assert not out.region[20:100, 200:280].any()
    assert not ObjectFilter(min_points=25)(ctx).dynamic.any()  # "more than N"
    assert not ObjectFilter(min_points=20, classes=["person"])(ctx).dynamic.any()


def test_build_filters_validates_names_and_parameters() -> None:
    filters = build_filters(["semantic", "geometry"], {"semantic": {"dilation": 9}})
    assert [f.name for f in filters] == ["semantic", "geometry"]
    assert filters[0].dilation == 9
    with pytest.raises(UssSlamError, match="unknown filter 'optical'; choose from semantic, flow"):
        build_filters(["optical"])
    with pytest.raises(UssSlamError, match="filter 'flow': bad parameters"):
        build_filters(["flow"], {"flow": {"tau": 3}})
    with pytest.raises(UssSlamError, match="listed twice"):
        build_filters(["flow", "flow"])
    with pytest.raises(UssSlamError, match="^slam.filter_params.semantic.dynamic_classes: "
                                           "unknown class 'dog'"):  # fmt: skip
        build_filters(["semantic"], {"semantic": {"dynamic_classes": ["dog"]}})
    with pytest.raises(UssSlamError, match="^slam.filter_params.object.classes: unknown class"):
        build_filters(["object"], {"object": {"classes": ["dog"]}})


def test_each_shipped_filter_node_names_its_class_and_its_constructor_defaults() -> None:
    nodes = shipped_filter_configs()
    assert list(nodes) == ["semantic", "flow", "geometry", "object"]  # the documented order
    classes = [SemanticFilter, FlowFilter, GeometryFilter, ObjectFilter]
    for (name, node), cls in zip(nodes.items(), classes, strict=True):
        assert node["_target_"] == f"{cls.__module__}.{cls.__qualname__}" and cls.name == name
        assert {k: v for k, v in node.items() if k != "_target_"} == filter_defaults()[name]
    built = build_filters(list(nodes))
    assert [type(f) for f in built] == classes


def test_a_filter_node_with_its_own_target_adds_a_filter() -> None:
    node = {"_target_": "uss_slam.slam_eval.filters.semantic.SemanticFilter", "dilation": 2}
    (extra,) = build_filters(["wide"], {"wide": node})
    assert isinstance(extra, SemanticFilter) and extra.dilation == 2
    with pytest.raises(UssSlamError, match="slam.filter_params.bare: expected a _target_"):
        build_filters(["bare"], {"bare": {"dilation": 2}})

"""The contract every shipped filter keeps, one test per filter node of
``configs/slam/orb_rgbd.yaml``: a new node is tested here without another list to edit.

A filter declares its stage; its node holds its constructor's defaults; its parameters have a
row in ``docs/slam-filters.md``; on a real frame (a synthetic walker sequence, one keyframe in
the map) it returns one bool per keypoint, a region of the image's shape or none, and at most as
many checked keypoints as there are, and leaves the frame, its keypoints and the map as they
were; a filter that needs labels refuses a frame without them in one line; a filter that can
blank ORB-SLAM3's input (``masks_input``) finds an image-sized region in the frame alone.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.config import filter_defaults
from uss_slam.slam_eval.filters.base import STAGES, DynamicFilter, FilterContext, FilterOutput
from uss_slam.slam_eval.filters.build import build_filters, filter_classes, shipped_filter_configs
from uss_slam.slam_eval.filters.chain import FilterChain
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.map.slam_map import SlamMap
from uss_slam.slam_eval.sequence import TumSequence

SHIPPED = sorted(shipped_filter_configs())
DOC = Path(__file__).resolve().parents[3] / "docs" / "slam-filters.md"


def test_every_filter_of_the_config_is_tested_here() -> None:
    assert sorted(filter_classes()) == SHIPPED and {"semantic", "geometry"} <= set(SHIPPED)


@pytest.fixture(scope="module")
def scene(synthetic_sequence) -> dict:
    """Frames 0 (a keyframe at the ground-truth pose) and 6 (tracked at its ground-truth pose)
    of a walking sequence with labels, the frame's ORB features and the map."""
    seq = TumSequence(synthetic_sequence(preset="walking_xyz", frames=8, size=(320, 240)),
                      load_labels=True)  # fmt: skip
    frames = {f.index: f for f in seq.frames()}
    ex = OrbExtractor(OrbConfig(n_features=500), seq.camera)
    truth = seq.groundtruth
    nearest = np.searchsorted(truth.stamps, [frames[0].stamp, frames[6].stamp])
    gt = {i: truth.matrices()[min(k, len(truth) - 1)] for i, k in zip((0, 6), nearest, strict=True)}
    first = ex(frames[0].gray, frames[0].depth)
    slam_map = SlamMap(ex.config.scale_factor, ex.config.n_levels)
    kf = slam_map.add_keyframe(0, frames[0].stamp, gt[0], first, np.full(len(first), -1),
                               np.zeros(len(first), bool), first.has_depth)  # fmt: skip
    kf.depth = frames[0].depth[:: kf.depth_stride, :: kf.depth_stride].copy()
    return {"frames": frames, "ex": ex, "map": slam_map, "pose": gt[6],
            "features": ex(frames[6].gray, frames[6].depth)}  # fmt: skip


def _context(scene: dict, labels: bool = True) -> FilterContext:
    frame = scene["frames"][6]
    features = scene["features"]
    ctx = FilterContext(frame, features, frame.labels if labels else None, scene["ex"],
                        scene["map"], scene["frames"][5], pose_wc=scene["pose"].copy(),
                        matched=np.full(len(features), -1, np.int64))  # fmt: skip
    ctx.motion_flags = np.zeros(len(features), bool)
    return ctx


@pytest.mark.parametrize("name", SHIPPED)
def test_a_filter_declares_its_stage_and_its_node_holds_its_defaults(name: str) -> None:
    node = shipped_filter_configs()[name]
    cls = filter_classes()[name]
    assert issubclass(cls, DynamicFilter) and cls.name == name
    assert node["_target_"] == f"{cls.__module__}.{cls.__qualname__}"
    assert cls.stage in STAGES
    assert {k: v for k, v in node.items() if k != "_target_"} == filter_defaults()[name]


@pytest.mark.parametrize("name", SHIPPED)
def test_a_filter_has_its_doc_rows(name: str) -> None:
    text = DOC.read_text(encoding="utf-8")
    assert re.search(rf"^- `{name}` \(", text, re.M), f"{DOC.name}: no bullet for {name}"
    rows = "\n".join(line for line in text.splitlines() if line.startswith("| `"))
    for param in filter_defaults()[name]:
        assert f"`{name}.{param}`" in rows, f"{DOC.name}: no table row for {name}.{param}"


@pytest.mark.parametrize("name", SHIPPED)
def test_a_filter_judges_the_frame_and_changes_nothing_it_reads(scene, name: str) -> None:
    (f,) = build_filters([name])
    ctx = _context(scene)
    n = len(ctx.features)
    xy, keyframes, points = ctx.features.xy.copy(), len(ctx.map.keyframes), ctx.map.n_points
    depth = ctx.frame.depth.copy()
    out = f(ctx)
    assert isinstance(out, FilterOutput)
    assert out.dynamic.shape == (n,) and out.dynamic.dtype == bool
    assert out.region is None or (
        out.region.shape == ctx.frame.depth.shape and out.region.dtype == bool
    )
    assert 0 <= out.checked <= n
    assert np.array_equal(ctx.features.xy, xy) and np.array_equal(ctx.frame.depth, depth)
    assert len(ctx.map.keyframes) == keyframes and ctx.map.n_points == points


@pytest.mark.parametrize("name", SHIPPED)
def test_a_filter_runs_in_the_chain_at_its_stage(scene, name: str) -> None:
    (f,) = build_filters([name])
    timed: list[str] = []

    class Clock:
        def __init__(self, what: str) -> None:
            timed.append(what)

        def __enter__(self) -> None: ...

        def __exit__(self, *exc: object) -> None: ...

    chain = FilterChain([f], Clock)
    frame = chain.frame(_context(scene))
    frame.pre()
    assert timed == ([f"filter.{name}"] if f.stage == "pre" else [])
    frame.after_pose(scene["pose"], np.full(len(scene["features"]), -1, np.int64))
    assert timed == [f"filter.{name}"]
    assert chain.counts["dropped"][name] == int(frame.dynamic.sum())
    assert chain.counts["flagged"][name] == int(frame.ctx.flags[name].sum())


@pytest.mark.parametrize("name", SHIPPED)
def test_a_filter_that_needs_labels_refuses_a_frame_without(scene, name: str) -> None:
    (f,) = build_filters([name])
    ctx = _context(scene, labels=False)
    ctx.motion_flags = np.ones(len(ctx.features), bool)  # the object rule looks at them first
    if not f.needs_labels:
        assert f(ctx).dynamic.shape == (len(ctx.features),)
        return
    with pytest.raises(UssSlamError, match=rf"^filter {name} needs a segmenter") as err:
        f(ctx)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("name", SHIPPED)
def test_a_filter_that_masks_orbslam3_input_finds_its_pixels_in_the_frame(scene, name) -> None:
    (f,) = build_filters([name])
    frame = scene["frames"][6]
    region = f.input_region(frame, frame.labels)
    if not f.masks_input:
        assert region is None and f.input_settings() == {}
        return
    assert region is not None and region.shape == frame.depth.shape and region.dtype == bool
    assert region.any()  # the walkers of the frame
    # the region it blanks is the one it keeps out of the harness's map
    out = f(_context(scene))
    assert out.region is not None and np.array_equal(region, out.region)


def test_a_filter_that_declares_no_stage_is_one_line_when_built() -> None:
    node = {"nostage": {"_target_": "filter_helpers.NoStage"}}
    with pytest.raises(UssSlamError) as err:
        build_filters(["nostage"], node)
    assert str(err.value).startswith(
        "filter 'nostage' (filter_helpers.NoStage) declares no stage: set its class attribute "
        "stage to 'pre' or 'post'"
    )
    assert "\n" not in str(err.value)
    with pytest.raises(UssSlamError, match=r"_target_: builtins.dict is not a DynamicFilter"):
        build_filters(["plain"], {"plain": {"_target_": "builtins.dict"}})

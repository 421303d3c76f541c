"""Semantic OctoMap: OctoMap's voxel keys, occupied voxels and their majority labels, free space
carved by later rays, dynamic pixels left out, the ``.ot`` file read back, the run's outputs and
the one-line error without pyoctomap."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import slam_run_config

from uss_slam.core.classes import CLASS_COLORS
from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.geometry import transform
from uss_slam.slam_eval.products.octomap import (
    OctoMapBuilder,
    key_centres,
    read_octomap,
    voxel_keys,
)
from uss_slam.slam_eval.products.semantic_map import MapConfig
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline

pyoctomap = pytest.importorskip("pyoctomap")

CAM = TUM_CAMERAS["fr3"].scaled(64, 48)
RES = 0.05


def _keyframe(depth_m: float = 2.0):
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[:] = (10, 200, 30)
    depth = np.full((48, 64), depth_m, np.float32)
    depth[:, :8] = 0.0  # no measurement
    labels = np.zeros((48, 64), np.uint8)
    labels[10:20, 40:50] = 3  # monitor
    labels[30:40, 10:20] = 1  # person
    return rgb, depth, labels


def _expected_keys(ex: OrbExtractor, pose: np.ndarray, depth: np.ndarray, keep: np.ndarray):
    rows, cols = np.nonzero(keep)
    xy = np.stack([cols, rows], axis=1).astype(np.float64)
    world = transform(pose, ex.backproject(ex.undistort(xy), depth[rows, cols]))
    return {tuple(k) for k in voxel_keys(world, RES)}


def _occupied_leaf_voxels(tree) -> int:
    """Occupied volume of a tree in voxels of its resolution, from OctoMap's own leaf iterator."""
    res = tree.getResolution()
    total = 0
    for leaf in tree.begin_leafs():
        if tree.isNodeOccupied(leaf):
            total += round(leaf.getSize() / res) ** 3
    return total


def test_voxel_keys_are_octomaps() -> None:
    tree = pyoctomap.OcTree(RES)
    points = np.random.default_rng(0).uniform(-3, 3, (200, 3))
    points[:4] = [[0, 0, 0], [RES, -RES, 2 * RES], [-1e-7, 0.5, 1.0], [0.1, 0.15, -0.25]]
    ours = voxel_keys(points, RES)
    for p, k in zip(points, ours, strict=True):
        key = tree.coordToKey(p)
        assert (key[0], key[1], key[2]) == tuple(k)
    np.testing.assert_array_equal(voxel_keys(key_centres(ours, RES), RES), ours)


def test_occupied_voxels_labels_colours_and_the_file(tmp_path: Path) -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    rgb, depth, labels = _keyframe()
    dynamic = labels == 1
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 2.0, 3.0)
    builder = OctoMapBuilder(MapConfig(stride=1, octomap=True, octomap_resolution=RES), ex)
    builder.add(0, rgb, depth, labels, dynamic)
    octo = builder.build(lambda kf: pose)
    # Every measured voxel of the one keyframe is occupied, and nothing else.
    keep = (depth > 0) & ~dynamic
    assert {tuple(k) for k in octo.keys} == _expected_keys(ex, pose, depth, keep)
    assert octo.per_class["person"] == 0 and 1 not in octo.labels  # the person is left out
    assert octo.per_class["monitor"] > 0 and octo.per_class["background"] > 0
    assert sum(octo.per_class.values()) == octo.occupied
    # Majority per voxel, from the pixels' own votes.
    rows, cols = np.nonzero(keep)
    world = transform(pose, ex.backproject(ex.undistort(np.stack([cols, rows], 1) * 1.0),
                                           depth[rows, cols]))  # fmt: skip
    votes = voxel_keys(world, RES)
    for key, label in zip(octo.keys[::7], octo.labels[::7], strict=True):
        mine = labels[rows, cols][(votes == key).all(axis=1)]
        assert label == np.bincount(mine).argmax()
    monitor = octo.labels == 3
    np.testing.assert_array_equal(
        octo.colors[monitor], np.tile(CLASS_COLORS[3], (monitor.sum(), 1))
    )
    np.testing.assert_array_equal(octo.colors[octo.labels == 0][0], (10, 200, 30))
    # Written and read back: the same occupied voxels with the same colours.
    octo.write(tmp_path / "octomap.ot")
    back = read_octomap(tmp_path / "octomap.ot")
    assert back.getTreeType() == "ColorOcTree" and back.getResolution() == pytest.approx(RES)
    assert _occupied_leaf_voxels(back) == octo.occupied
    for centre, colour in zip(key_centres(octo.keys, RES), octo.colors, strict=True):
        node = back.search(centre)
        assert back.isNodeOccupied(node) and node.getColor() == tuple(int(c) for c in colour)
    summary = octo.summary()
    assert summary["occupied_voxels"] == octo.occupied and summary["keyframes"] == 1
    assert summary["cpu_ms_per_keyframe"] > 0


def test_later_rays_carve_what_left(tmp_path: Path) -> None:
    """A chair seen once at 1 m in front of a wall at 2 m, then gone in three later keyframes
    from the same place: OctoMap's misses (log-odds -0.41 each) outweigh its one hit (+0.85)."""
    ex = OrbExtractor(OrbConfig(), CAM)
    rgb, wall, _ = _keyframe()
    labels = np.zeros((48, 64), np.uint8)
    with_chair = wall.copy()
    with_chair[20:30, 30:40] = 1.0
    labels[20:30, 30:40] = 2  # chair
    builder = OctoMapBuilder(MapConfig(stride=1, octomap=True, octomap_resolution=RES), ex)
    builder.add(0, rgb, with_chair, labels, None)
    for kf in (1, 2, 3):
        builder.add(kf, rgb, wall, np.zeros_like(labels), None)
    octo = builder.build(lambda kf: np.eye(4))
    assert octo.per_class["chair"] == 0
    assert {tuple(k) for k in octo.keys} == _expected_keys(ex, np.eye(4), wall, wall > 0)
    assert octo.summary()["measured_voxels_carved"] > 0
    once = OctoMapBuilder(MapConfig(stride=1, octomap=True, octomap_resolution=RES), ex)
    once.add(0, rgb, with_chair, labels, None)
    once.add(1, rgb, wall, np.zeros_like(labels), None)  # one miss is not enough
    assert once.build(lambda kf: np.eye(4)).per_class["chair"] > 0


def test_a_run_writes_the_semantic_octomap(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=30)
    out = tmp_path / "run"
    cfg = slam_run_config(
        path, out, "segmenter=labels", "filters=[semantic]", "slam.map.octomap=true"
    )
    data = run(cfg)
    octo = data["octomap"]
    counts = octo["occupied_per_class"]
    assert octo["occupied_voxels"] > 1000 and octo["resolution"] == 0.05
    assert counts["monitor"] > 0 and counts["background"] > 0 and counts["unknown"] == 0
    assert counts["person"] == 0  # the seated people's pixels are the semantic filter's region
    assert json.loads((out / "metrics.json").read_text())["octomap"] == octo
    back = read_octomap(out / "octomap.ot")
    assert _occupied_leaf_voxels(back) == octo["occupied_voxels"]
    report = (out / "report.md").read_text()
    assert f"Semantic OctoMap: `octomap.ot`, 0.05 m voxels, {octo['occupied_voxels']} occupied" in (
        report
    )
    # Without the filter the same people do land in the map.
    unfiltered = SlamPipeline(
        TumSequence(path, load_labels=True),
        LabelsSegmenter(),
        build_filters([]),
        semantic_map=MapConfig(octomap=True),
        progress=False,
    ).run()
    assert unfiltered.octomap is not None and unfiltered.octomap.per_class["person"] > 0
    # With the back end every keyframe goes in at its final pose, the people still left out.
    adjusted = SlamPipeline(
        TumSequence(path, load_labels=True),
        LabelsSegmenter(),
        build_filters(["semantic"]),
        semantic_map=MapConfig(octomap=True),
        local_ba=True,
        progress=False,
    ).run()
    assert adjusted.octomap is not None and adjusted.octomap.keyframes == adjusted.keyframes
    assert adjusted.octomap.per_class["person"] == 0 and adjusted.octomap.occupied > 1000


def test_off_by_default_and_a_missing_pyoctomap_is_one_line(
    synthetic_sequence, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=30)
    assert MapConfig().octomap is False
    monkeypatch.setitem(sys.modules, "pyoctomap", None)  # import fails as if not installed
    seq = TumSequence(path)
    with pytest.raises(UssSlamError, match=r"pip install 'uss-slam\[octomap\]'"):
        SlamPipeline(seq, NoSegmenter(), [], semantic_map=MapConfig(octomap=True))
    SlamPipeline(seq, NoSegmenter(), [], semantic_map=MapConfig())  # off: pyoctomap not needed
    with pytest.raises(ValueError, match="octomap_resolution: expected a number > 0"):
        MapConfig(octomap=True, octomap_resolution=0.0)

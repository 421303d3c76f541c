"""Semantic point cloud: back-projection with the keyframe pose, dynamic pixels left out,
class colours, voxel merging, PLY round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uss_slam.core.classes import CLASS_COLORS, CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import DataFormatError
from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.products.semantic_map import (
    PLY_RECORD,
    MapConfig,
    PointCloud,
    SemanticMapBuilder,
    _voxel_index,
    read_ply,
    write_ply,
)

CAM = TUM_CAMERAS["fr3"].scaled(64, 48)


def _keyframe():
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[:] = (10, 200, 30)
    depth = np.full((48, 64), 2.0, np.float32)
    depth[:, :8] = 0.0  # no measurement
    labels = np.zeros((48, 64), np.uint8)
    labels[10:20, 40:50] = 3  # monitor
    labels[30:40, 10:20] = 1  # person
    return rgb, depth, labels


def test_keyframe_points_colours_and_dynamic_pixels() -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    rgb, depth, labels = _keyframe()
    dynamic = labels == 1
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 2.0, 3.0)
    builder = SemanticMapBuilder(MapConfig(stride=1, voxel=1e-4), ex)
    builder.add(pose, rgb, depth, labels, dynamic)
    cloud = builder.build()
    expected = int(((depth > 0) & ~dynamic).sum())
    assert len(cloud) == expected  # tiny voxels: one point per pixel
    np.testing.assert_allclose(cloud.points[:, 2], 5.0, atol=1e-5)  # depth 2 m + pose z 3 m
    assert CLASS_NAMES.index("person") not in cloud.labels  # the person is left out
    monitor = cloud.labels == 3
    assert monitor.sum() == 100
    np.testing.assert_array_equal(cloud.colors[monitor], np.tile(CLASS_COLORS[3], (100, 1)))
    np.testing.assert_array_equal(cloud.colors[cloud.labels == 0][0], (10, 200, 30))  # image colour
    # One pixel's position, by the pinhole model.
    row, col = 15, 45
    x = (col - CAM.cx) * 2.0 / CAM.fx + 1.0
    y = (row - CAM.cy) * 2.0 / CAM.fy + 2.0
    assert np.min(np.linalg.norm(cloud.points - [x, y, 5.0], axis=1)) < 1e-5


def test_voxels_merge_points_and_keep_the_majority_label() -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    rgb, depth, labels = _keyframe()
    fine = SemanticMapBuilder(MapConfig(stride=1, voxel=1e-4), ex)
    fine.add(np.eye(4), rgb, depth, labels, None)
    raw = fine.build()  # one point per pixel
    builder = SemanticMapBuilder(MapConfig(stride=1, voxel=0.5), ex)
    builder.add(np.eye(4), rgb, depth, labels, None)
    builder.add(np.eye(4), rgb, depth, labels, None)  # the same view twice: no new voxels
    cloud = builder.build()
    keys = np.floor(raw.points / 0.5).astype(int)
    voxels, inverse = np.unique(keys, axis=0, return_inverse=True)
    assert len(cloud) == len(voxels)
    cloud_keys = [tuple(k) for k in np.floor(cloud.points / 0.5).astype(int)]
    for v, key in enumerate(voxels):
        members = inverse.reshape(-1) == v
        at = cloud_keys.index(tuple(key))
        assert cloud.labels[at] == np.bincount(raw.labels[members]).argmax()  # majority label
        np.testing.assert_allclose(cloud.points[at], raw.points[members].mean(axis=0), atol=1e-5)
    no_labels = SemanticMapBuilder(MapConfig(stride=4, voxel=0.01), ex)
    no_labels.add(np.eye(4), rgb, depth, None, None)
    assert set(no_labels.build().labels.tolist()) == {IGNORE_INDEX}


def test_ply_round_trip(tmp_path: Path) -> None:
    ex = OrbExtractor(OrbConfig(), CAM)
    rgb, depth, labels = _keyframe()
    builder = SemanticMapBuilder(MapConfig(stride=2, voxel=0.01), ex)
    builder.add(np.eye(4), rgb, depth, labels, None)
    cloud = builder.build()
    write_ply(tmp_path / "map.ply", cloud)
    header = (tmp_path / "map.ply").read_bytes()[:400].decode("ascii", "replace")
    assert header.startswith("ply\nformat binary_little_endian 1.0\n")
    assert f"element vertex {len(cloud)}\n" in header and "property uchar label" in header
    back = read_ply(tmp_path / "map.ply")
    np.testing.assert_array_equal(back.points, cloud.points)
    np.testing.assert_array_equal(back.colors, cloud.colors)
    np.testing.assert_array_equal(back.labels, cloud.labels)
    empty = SemanticMapBuilder(MapConfig(), ex).build()
    write_ply(tmp_path / "empty.ply", empty)
    assert len(read_ply(tmp_path / "empty.ply")) == 0


def test_ply_layout_is_checked_when_read(tmp_path: Path) -> None:
    cloud = PointCloud(
        np.arange(6, dtype=np.float32).reshape(2, 3),
        np.array([[1, 2, 3], [4, 5, 6]], np.uint8),
        np.array([0, 2], np.uint8),
    )
    path = tmp_path / "map.ply"
    write_ply(path, cloud)
    raw = path.read_bytes()
    assert len(raw) - raw.index(b"end_header\n") - len(b"end_header\n") == 2 * PLY_RECORD.itemsize
    path.write_bytes(raw[:-3])
    with pytest.raises(DataFormatError, match=r"map\.ply: the header announces 2 vertices"):
        read_ply(path)
    path.write_bytes(raw.replace(b"property uchar label\n", b"property float label\n"))
    with pytest.raises(DataFormatError, match="not a uss-slam semantic map"):
        read_ply(path)
    path.write_bytes(b"solid stl\n")
    with pytest.raises(DataFormatError, match="not a PLY file"):
        read_ply(path)


@pytest.mark.parametrize("far", [False, True])
def test_voxel_index_is_numpys_row_unique_inverse(far: bool) -> None:
    """The packed 1-D index equals ``np.unique(keys, axis=0)``'s inverse (the order of the
    voxels, hence map.ply, is unchanged); keys too far apart to pack fall back to it."""
    rng = np.random.default_rng(3)
    keys = np.floor(rng.normal(0.0, 2.0, (5000, 3)) / 0.02).astype(np.int64)
    keys[1::2] = keys[::2][: len(keys[1::2])]  # every voxel holds several points
    keys[7] = [-40, 3, 9]
    if far:
        keys[11] = [2**40, -(2**40), 2**30]
    expected = np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1)
    np.testing.assert_array_equal(_voxel_index(keys), expected)

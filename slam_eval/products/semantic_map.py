"""Semantic point cloud of the static scene, built from keyframes (USS-SLAM §3.7, robust semantic
mapping §3.3) and written as PLY.

Each keyframe contributes its depth pixels (every ``stride``-th pixel, within the depth range)
back-projected with its pose, minus the pixels its dynamic filters marked (the dilated mask of the
dynamic classes, the grown geometry regions, whole moving objects). Points are merged in a voxel
grid (one point per ``voxel`` metres cube: mean position, colour of the most frequent class).
Points of a segmented class take ``classes.CLASS_COLORS``; background keeps the image colour, so
the map is readable without segmentation too. The PLY stores ``x y z`` (float32, metres, world =
first camera frame), ``red green blue`` and ``label`` (uint8 class id, 255 = unknown).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uss_slam.core.classes import CLASS_COLORS, IGNORE_INDEX
from uss_slam.core.errors import DataFormatError
from uss_slam.core.schema import check_fields, ranged
from uss_slam.core.tum_io import StrPath

from ..frontend.orb import OrbExtractor
from ..geometry import transform


@dataclass(frozen=True)
class MapConfig:
    stride: int = ranged(4, min=1)
    """Use every ``stride``-th pixel of a keyframe in both directions."""
    voxel: float = ranged(0.02, gt=0)
    """Voxel size of the merged cloud, metres."""
    max_depth: float = ranged(4.0, gt=0)
    """Ignore depth beyond this (noisy), metres."""
    octomap: bool = False
    """Also build a semantic OctoMap (``octomap.ot``, :mod:`.octomap`; needs pyoctomap)."""
    octomap_resolution: float = ranged(0.05, gt=0, needs="octomap")
    """Voxel size of the OctoMap, metres."""

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass
class PointCloud:
    """``points`` (N, 3) float32 metres, ``colors`` (N, 3) uint8 RGB, ``labels`` (N,) uint8."""

    points: np.ndarray
    colors: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


class SemanticMapBuilder:
    """Accumulates keyframes into a voxel-merged semantic point cloud."""

    def __init__(self, config: MapConfig, extractor: OrbExtractor) -> None:
        self.config = config
        self.extractor = extractor
        self._chunks: list[PointCloud] = []
        self.keyframes = 0

    def add(
        self,
        pose_wc: np.ndarray,
        rgb: np.ndarray,
        depth: np.ndarray,
        labels: np.ndarray | None,
        dynamic: np.ndarray | None,
    ) -> None:
        """Add one keyframe: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) metres, ``labels`` (H, W)
        uint8 or None, ``dynamic`` (H, W) bool pixels to leave out or None."""
        cam, colors, lab = keyframe_pixels(self.extractor, self.config, rgb, depth, labels, dynamic)
        if len(cam) == 0:
            self.keyframes += 1
            return
        world = transform(pose_wc, cam).astype(np.float32)
        if labels is not None:
            known = (lab > 0) & (lab < len(CLASS_COLORS))
            colors = colors.copy()
            colors[known] = CLASS_COLORS[lab[known]]
        self._chunks.append(_voxelise(PointCloud(world, colors, lab), self.config.voxel))
        self.keyframes += 1

    def build(self) -> PointCloud:
        """The merged cloud of every keyframe added so far."""
        return merge_clouds(self._chunks, self.config.voxel)


def keyframe_pixels(
    extractor: OrbExtractor,
    config: MapConfig,
    rgb: np.ndarray,
    depth: np.ndarray,
    labels: np.ndarray | None,
    dynamic: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels a keyframe gives the maps: every ``config.stride``-th pixel with depth in
    (0, ``config.max_depth``], minus ``dynamic``; as camera-frame points (N, 3) float64, their
    image colours (N, 3) uint8 and labels (N,) uint8 (``IGNORE_INDEX`` without ``labels``)."""
    s = config.stride
    d = depth[::s, ::s]
    keep = (d > 0) & (d <= config.max_depth)
    if dynamic is not None:
        keep &= ~dynamic[::s, ::s]
    rows, cols = np.nonzero(keep)
    if len(rows) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.uint8)
    xy = np.stack([cols * s, rows * s], axis=1).astype(np.float64)
    cam = extractor.backproject(extractor.undistort(xy), d[rows, cols])
    colors = rgb[::s, ::s][rows, cols]
    if labels is None:
        lab = np.full(len(rows), IGNORE_INDEX, np.uint8)
    else:
        lab = labels[::s, ::s][rows, cols].astype(np.uint8)
    return cam, colors, lab


def merge_clouds(clouds: list[PointCloud], voxel: float) -> PointCloud:
    """One voxel-merged cloud of ``clouds`` (keyframe clouds in one frame, e.g. the world)."""
    if not clouds:
        return PointCloud(
            np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), np.zeros(0, np.uint8)
        )
    merged = PointCloud(
        np.concatenate([c.points for c in clouds]),
        np.concatenate([c.colors for c in clouds]),
        np.concatenate([c.labels for c in clouds]),
    )
    return _voxelise(merged, voxel)


def _voxel_index(keys: np.ndarray) -> np.ndarray:
    """``(N,)`` index of each row of the ``(N, 3)`` integer voxel ``keys`` among the distinct
    rows in lexicographic order: ``np.unique(keys, axis=0, return_inverse=True)[1]``, computed
    on one packed integer per row (a 1-D sort, several times faster than sorting rows)."""
    low = keys.min(axis=0)
    span = keys.max(axis=0) - low + 1
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0**62:  # cannot pack: sort rows
        return np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1)
    shifted = keys - low
    packed = (shifted[:, 0] * span[1] + shifted[:, 1]) * span[2] + shifted[:, 2]
    return np.unique(packed, return_inverse=True)[1].reshape(-1)


def _voxelise(cloud: PointCloud, voxel: float) -> PointCloud:
    """One point per occupied voxel: mean position, most frequent label and its mean colour."""
    if len(cloud) == 0:
        return cloud
    keys = np.floor(cloud.points / voxel).astype(np.int64)
    inverse = _voxel_index(keys)
    n = int(inverse.max()) + 1
    counts = np.bincount(inverse, minlength=n).astype(np.float64)
    points = np.stack(
        [np.bincount(inverse, cloud.points[:, k], minlength=n) / counts for k in range(3)], axis=1
    ).astype(np.float32)
    # Majority label per voxel: count (voxel, label) pairs and keep the largest per voxel.
    pair = inverse * 256 + cloud.labels.astype(np.int64)
    values, pair_counts = np.unique(pair, return_counts=True)
    order = np.lexsort((-pair_counts, values // 256))
    first = np.r_[True, (values[order] // 256)[1:] != (values[order] // 256)[:-1]]
    labels = np.zeros(n, np.uint8)
    labels[values[order][first] // 256] = (values[order][first] % 256).astype(np.uint8)
    agree = cloud.labels == labels[inverse]
    sel = inverse[agree]
    colors = np.stack(
        [
            np.bincount(sel, cloud.colors[agree, k].astype(np.float64), minlength=n)
            / np.maximum(np.bincount(sel, minlength=n), 1)
            for k in range(3)
        ],
        axis=1,
    )
    return PointCloud(points, np.clip(np.rint(colors), 0, 255).astype(np.uint8), labels)


PLY_RECORD = np.dtype(
    [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("r", "u1"),
        ("g", "u1"),
        ("b", "u1"),
        ("l", "u1"),
    ]
)
"""One vertex of ``map.ply`` as stored (little-endian, 16 bytes)."""

PLY_PROPERTIES = (
    "property float x\nproperty float y\nproperty float z\n"
    "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    "property uchar label\n"
)
"""The header lines that describe :data:`PLY_RECORD`."""


def write_ply(path: StrPath, cloud: PointCloud) -> None:
    """Binary little-endian PLY with ``x y z`` float32, ``red green blue label`` uint8."""
    n = len(cloud)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        "comment uss-slam semantic map (world = first camera frame, metres)\n"
        f"element vertex {n}\n{PLY_PROPERTIES}end_header\n"
    )
    data = np.empty(n, PLY_RECORD)
    data["x"], data["y"], data["z"] = cloud.points.T
    data["r"], data["g"], data["b"] = cloud.colors.T
    data["l"] = cloud.labels
    with Path(path).open("wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(data.tobytes())


def read_ply(path: StrPath) -> PointCloud:
    """Read a PLY written by :func:`write_ply` (for tests and quick inspection); another layout
    is a :class:`DataFormatError` naming the file."""
    path = Path(path)
    raw = path.read_bytes()
    marker = b"end_header\n"
    if not raw.startswith(b"ply\n") or marker not in raw:
        raise DataFormatError(path, "not a PLY file (no 'ply' ... 'end_header' header)")
    end = raw.index(marker) + len(marker)
    header = raw[:end].decode("ascii", errors="replace")
    counts = [line.split() for line in header.splitlines() if line.startswith("element vertex")]
    if (
        "format binary_little_endian 1.0\n" not in header
        or PLY_PROPERTIES not in header
        or len(counts) != 1
        or not counts[0][2].isdigit()
    ):
        raise DataFormatError(path, "not a uss-slam semantic map (unexpected PLY header)")
    n = int(counts[0][2])
    if len(raw) - end != n * PLY_RECORD.itemsize:
        raise DataFormatError(
            path,
            f"the header announces {n} vertices ({n * PLY_RECORD.itemsize} bytes) but "
            f"{len(raw) - end} bytes follow it",
        )
    data = np.frombuffer(raw[end:], PLY_RECORD, count=n)
    return PointCloud(
        np.stack([data["x"], data["y"], data["z"]], axis=1),
        np.stack([data["r"], data["g"], data["b"]], axis=1),
        data["l"].copy(),
    )

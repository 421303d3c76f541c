"""Semantic OctoMap of the static scene (PSPNet-SLAM §III-E), built from keyframes and written as
``octomap.ot``.

Switched on by ``slam.map.octomap=true`` (needs the ``octomap`` extra: ``pip install
'uss-slam[octomap]'``, which brings pyoctomap, the OctoMap library's binding). Each keyframe
contributes the pixels the semantic point cloud uses (every ``stride``-th pixel with depth in
``(0, max_depth]``, minus the pixels its dynamic filters marked). At the end of the run they are
integrated into an OctoMap ``ColorOcTree`` of ``octomap_resolution`` metres, keyframe after
keyframe, each with its final pose (after local BA / loop closing when those are on): a ray from
the camera centre to each measured voxel marks the voxels it crosses free and the end voxel
occupied, with OctoMap's probabilistic update (log-odds, hit 0.7, miss 0.4, clamped to
[0.12, 0.97]). So a thing that slipped through the dynamic filters in one keyframe is carved away
again when later keyframes see through the place it stood. The end points of one keyframe are
taken per voxel (one ray to each measured voxel's centre, as OctoMap's discretised insertion).

Semantics: every measured end point votes for its class in the voxel it falls in (a count per
class, kept beside the tree keyed by the voxel's OctoMap key); an occupied voxel's label is the
class with most votes (ties: the lower class id; 255 = unknown when no segmentation ran). The
written tree is expanded to single voxels (no pruning, so no two labels share a node) and each
occupied voxel is coloured like ``map.ply``: a segmented class with ``classes.CLASS_COLORS``, the
background with the mean image colour of its votes. Free voxels stay in the file (navigation).

Never imports torch; pyoctomap is imported only when the option is on.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.classes import CLASS_COLORS, CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import StrPath

from ..frontend.orb import OrbExtractor
from .semantic_map import MapConfig, keyframe_pixels

KEY_OFFSET = 32768
"""OctoMap's key of the voxel at the origin (tree depth 16): key = floor(x / resolution) + 32768."""
INSTALL_HINT = "slam.map.octomap=true needs pyoctomap: pip install 'uss-slam[octomap]'"


def load_pyoctomap() -> Any:
    """The pyoctomap module, or a :class:`UssSlamError` naming the extra to install."""
    try:
        import pyoctomap
    except ImportError as err:
        raise UssSlamError(f"{INSTALL_HINT} ({err})") from None
    return pyoctomap


def voxel_keys(points: np.ndarray, resolution: float) -> np.ndarray:
    """OctoMap keys ``(N, 3)`` int64 of ``points`` ``(N, 3)`` metres, as OctoMap computes them
    (coordinates in float32, as its point clouds hold them)."""
    scaled = points.astype(np.float32).astype(np.float64) * (1.0 / resolution)
    return np.floor(scaled).astype(np.int64) + KEY_OFFSET


def key_centres(keys: np.ndarray, resolution: float) -> np.ndarray:
    """Centres ``(N, 3)`` float64 metres of the voxels with OctoMap ``keys`` ``(N, 3)``."""
    return (keys - KEY_OFFSET + 0.5) * resolution


def _pack(keys: np.ndarray) -> np.ndarray:
    """One int64 per key (each component is 16 bits)."""
    return (keys[:, 0] << 32) | (keys[:, 1] << 16) | keys[:, 2]


def _unpack(packed: np.ndarray) -> np.ndarray:
    return np.stack([packed >> 32, (packed >> 16) & 0xFFFF, packed & 0xFFFF], axis=1)


@dataclass
class _Keyframe:
    """One keyframe's measurements in its camera frame: ``points`` (N, 3) float32 metres,
    ``labels`` (N,) uint8, ``colors`` (N, 3) uint8 RGB."""

    keyframe_id: int
    points: np.ndarray
    labels: np.ndarray
    colors: np.ndarray


@dataclass
class SemanticOctoMap:
    """The integrated map. ``tree``: the pyoctomap ``ColorOcTree`` (expanded, coloured);
    ``keys`` (M, 3) int64 OctoMap keys of the occupied voxels, ``labels`` (M,) uint8 their
    majority class, ``colors`` (M, 3) uint8 their colour in the tree."""

    tree: Any
    resolution: float
    keys: np.ndarray
    labels: np.ndarray
    colors: np.ndarray
    keyframes: int
    cpu_s: float
    """CPU seconds of the map (back-projection per keyframe + integration), this thread."""
    measured_voxels: int = 0
    """Voxels that received at least one end point (occupied now or carved away later)."""
    per_class: dict[str, int] = field(default_factory=dict)

    @property
    def occupied(self) -> int:
        return len(self.keys)

    def write(self, path: StrPath) -> None:
        """Write the tree as an OctoMap ``.ot`` file (ColorOcTree, readable by octovis and
        ``pyoctomap.ColorOcTree(path)``)."""
        if not self.tree.write(str(path)):
            raise UssSlamError(f"{path}: pyoctomap could not write the OctoMap")

    def summary(self) -> dict[str, Any]:
        """The ``octomap`` entry of ``metrics.json``."""
        return {
            "file": "octomap.ot",
            "resolution": self.resolution,
            "keyframes": self.keyframes,
            "occupied_voxels": self.occupied,
            "occupied_per_class": self.per_class,
            "measured_voxels_carved": self.measured_voxels - self.occupied,
            "tree_nodes": int(self.tree.size()),
            "cpu_ms_per_keyframe": 1000.0 * self.cpu_s / max(self.keyframes, 1),
        }


def class_counts(labels: np.ndarray) -> dict[str, int]:
    """Occupied voxels per class name (``unknown`` = 255, no segmentation)."""
    counts = {name: int((labels == i).sum()) for i, name in enumerate(CLASS_NAMES)}
    counts["unknown"] = int((labels == IGNORE_INDEX).sum())
    return counts


class OctoMapBuilder:
    """Collects keyframe measurements during the run and integrates them at the end (when every
    keyframe pose is final)."""

    def __init__(self, config: MapConfig, extractor: OrbExtractor) -> None:
        self.config = config
        self.extractor = extractor
        self.pyoctomap = load_pyoctomap()
        self._keyframes: list[_Keyframe] = []
        self._cpu = 0.0

    def add(
        self,
        keyframe_id: int,
        rgb: np.ndarray,
        depth: np.ndarray,
        labels: np.ndarray | None,
        dynamic: np.ndarray | None,
    ) -> None:
        """Keep one keyframe's measurements: ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) metres,
        ``labels`` (H, W) uint8 or None, ``dynamic`` (H, W) bool pixels to leave out or None
        (the same pixels as :meth:`.SemanticMapBuilder.add`)."""
        start = time.thread_time()
        cam, colors, lab = keyframe_pixels(self.extractor, self.config, rgb, depth, labels, dynamic)
        self._keyframes.append(_Keyframe(keyframe_id, cam.astype(np.float32), lab, colors))
        self._cpu += time.thread_time() - start

    def build(self, pose_wc: Callable[[int], np.ndarray]) -> SemanticOctoMap:
        """Integrate every keyframe, in order, with its pose ``pose_wc(keyframe_id)`` (4×4
        camera-to-world), and label and colour the occupied voxels."""
        start = time.thread_time()
        res = self.config.octomap_resolution
        tree = self.pyoctomap.ColorOcTree(res)
        votes_key: list[np.ndarray] = []
        votes_label: list[np.ndarray] = []
        votes_color: list[np.ndarray] = []
        for kf in self._keyframes:
            if len(kf.points) == 0:
                continue
            pose = pose_wc(kf.keyframe_id)
            world = kf.points.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
            packed = _pack(voxel_keys(world, res))
            ends = np.unique(packed)
            tree.insertPointCloud(
                np.ascontiguousarray(key_centres(_unpack(ends), res)),
                np.asarray(pose[:3, 3], np.float64),
                lazy_eval=True,
            )
            votes_key.append(packed)
            votes_label.append(kf.labels)
            votes_color.append(kf.colors)
        tree.updateInnerOccupancy()
        # No pruning from here on: a pruned node would merge voxels of different classes.
        tree.expand()
        if votes_key:
            packed = np.concatenate(votes_key)
            labels = np.concatenate(votes_label)
            colors = np.concatenate(votes_color)
        else:
            packed = np.zeros(0, np.int64)
            labels = np.zeros(0, np.uint8)
            colors = np.zeros((0, 3), np.uint8)
        voxels, inverse = np.unique(packed, return_inverse=True)
        inverse = inverse.reshape(-1)
        majority = _majority(inverse, labels, len(voxels))
        keys = _unpack(voxels)
        occupied = np.zeros(len(voxels), bool)
        for i, key in enumerate(key_centres(keys, res)):
            node = tree.search(key)
            occupied[i] = node is not None and tree.isNodeOccupied(node)
        agree = labels == majority[inverse]
        mean = np.stack(
            [
                np.bincount(inverse[agree], colors[agree, k].astype(np.float64), len(voxels))
                / np.maximum(np.bincount(inverse[agree], minlength=len(voxels)), 1)
                for k in range(3)
            ],
            axis=1,
        )
        shown = np.clip(np.rint(mean), 0, 255).astype(np.uint8)
        known = (majority > 0) & (majority < len(CLASS_COLORS))
        shown[known] = CLASS_COLORS[majority[known]]
        keys, majority, shown = keys[occupied], majority[occupied], shown[occupied]
        for key, (r, g, b) in zip(key_centres(keys, res), shown, strict=True):
            tree.setNodeColor(key, int(r), int(g), int(b))
        tree.updateInnerOccupancy()
        self._cpu += time.thread_time() - start
        return SemanticOctoMap(
            tree=tree,
            resolution=res,
            keys=keys,
            labels=majority,
            colors=shown,
            keyframes=len(self._keyframes),
            cpu_s=self._cpu,
            measured_voxels=len(voxels),
            per_class=class_counts(majority),
        )


def _majority(inverse: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Most frequent label per voxel (ties: the lower label); ``inverse`` (N,) voxel per vote."""
    if n == 0:
        return np.zeros(0, np.uint8)
    values, column = np.unique(labels, return_inverse=True)
    counts = np.zeros((n, len(values)), np.int64)
    np.add.at(counts, (inverse, column.reshape(-1)), 1)
    return values[counts.argmax(axis=1)].astype(np.uint8)


def read_octomap(path: StrPath) -> Any:
    """Read an ``octomap.ot`` back (a pyoctomap ``ColorOcTree``); a file OctoMap cannot read is
    a :class:`UssSlamError` naming it."""
    pyoctomap = load_pyoctomap()
    path = Path(path)
    if not path.is_file():
        raise UssSlamError(f"{path}: no such OctoMap file")
    try:
        return pyoctomap.ColorOcTree(str(path))
    except OSError:
        raise UssSlamError(f"{path}: not an OctoMap ColorOcTree (.ot) file") from None

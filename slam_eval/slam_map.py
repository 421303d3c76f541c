"""The tracker's map: keyframes and map points in growable NumPy arrays.

Map points carry what ORB-SLAM2's tracking needs: world position, two descriptors (from the
creating keyframe and the latest one observing the point), mean viewing direction, the distance
range over which ORB can re-detect the point (scale invariance), visible / found counters for
culling, and their keyframe observations (kept as flat ``(point, keyframe)`` pair arrays so that
covisibility counts are single ``np.bincount`` calls).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .frontend import Features
from .geometry import invert, transform


@dataclass
class KeyFrame:
    """A keyframe: its pose, keypoints and which map point each keypoint observes.

    ``pose_wc`` (4, 4) camera-to-world; ``point_ids`` (N,) int64 map point per keypoint (-1 none);
    ``dynamic`` (N,) bool keypoints the filters flagged.
    """

    id: int
    frame_index: int
    stamp: float
    pose_wc: np.ndarray
    features: Features
    point_ids: np.ndarray
    dynamic: np.ndarray
    depth: np.ndarray | None = None
    """Depth image subsampled by ``depth_stride`` (metres), for the multi-view geometry check."""
    depth_stride: int = 4

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, ``(3,)`` metres."""
        return self.pose_wc[:3, 3]

    @property
    def pose_cw(self) -> np.ndarray:
        return invert(self.pose_wc)


class _Growable:
    """A NumPy array that grows by doubling along its first axis."""

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype | type, fill: float = 0) -> None:
        self._data = np.full((64, *shape), fill, dtype=dtype)
        self._fill = fill
        self.size = 0

    def extend(self, values: np.ndarray) -> None:
        n = len(values)
        if self.size + n > len(self._data):
            capacity = max(2 * len(self._data), self.size + n)
            grown = np.full((capacity, *self._data.shape[1:]), self._fill, dtype=self._data.dtype)
            grown[: self.size] = self._data[: self.size]
            self._data = grown
        self._data[self.size : self.size + n] = values
        self.size += n

    @property
    def view(self) -> np.ndarray:
        return self._data[: self.size]


@dataclass
class MapPoints:
    """Growable per-point arrays; index = map point id."""

    position: _Growable = field(default_factory=lambda: _Growable((3,), np.float64))
    descriptor: _Growable = field(default_factory=lambda: _Growable((32,), np.uint8))
    latest_descriptor: _Growable = field(default_factory=lambda: _Growable((32,), np.uint8))
    normal: _Growable = field(default_factory=lambda: _Growable((3,), np.float64))
    max_distance: _Growable = field(default_factory=lambda: _Growable((), np.float64))
    min_distance: _Growable = field(default_factory=lambda: _Growable((), np.float64))
    visible: _Growable = field(default_factory=lambda: _Growable((), np.int32))
    found: _Growable = field(default_factory=lambda: _Growable((), np.int32))
    observations: _Growable = field(default_factory=lambda: _Growable((), np.int32))
    first_keyframe: _Growable = field(default_factory=lambda: _Growable((), np.int32))
    bad: _Growable = field(default_factory=lambda: _Growable((), bool))

    def __len__(self) -> int:
        return self.position.size


class SlamMap:
    """Keyframes, map points and their observations."""

    def __init__(self, scale_factor: float, n_levels: int) -> None:
        self.keyframes: list[KeyFrame] = []
        self.points = MapPoints()
        self._obs_point = _Growable((), np.int64)
        self._obs_keyframe = _Growable((), np.int64)
        self.scale_factor = scale_factor
        self.n_levels = n_levels
        self.culled = 0
        """Map points removed by culling so far."""

    # ------------------------------------------------------------------ queries

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_good(self) -> int:
        return int((~self.points.bad.view).sum())

    def covisibility(self, point_ids: np.ndarray) -> np.ndarray:
        """``(K,)`` per keyframe: how many of ``point_ids`` it observes."""
        counts = np.zeros(len(self.keyframes), np.int64)
        if len(point_ids) == 0 or self._obs_point.size == 0:
            return counts
        marked = np.zeros(self.n_points, bool)
        marked[point_ids] = True
        hit = marked[self._obs_point.view]
        return np.bincount(self._obs_keyframe.view[hit], minlength=len(self.keyframes)).astype(
            np.int64
        )

    def points_of(self, keyframe_ids: np.ndarray) -> np.ndarray:
        """Sorted ids of the good map points observed by any of ``keyframe_ids``."""
        if len(keyframe_ids) == 0 or self._obs_point.size == 0:
            return np.zeros(0, np.int64)
        marked = np.zeros(len(self.keyframes), bool)
        marked[keyframe_ids] = True
        ids = np.unique(self._obs_point.view[marked[self._obs_keyframe.view]])
        return ids[~self.points.bad.view[ids]]

    def predict_level(self, point_ids: np.ndarray, distance: np.ndarray) -> np.ndarray:
        """Pyramid level at which a point at ``distance`` should be detected (ORB-SLAM2 rule)."""
        ratio = self.points.max_distance.view[point_ids] / np.maximum(distance, 1e-9)
        level = np.ceil(np.log(np.maximum(ratio, 1e-9)) / np.log(self.scale_factor))
        return np.clip(level, 0, self.n_levels - 1).astype(np.int32)

    # ------------------------------------------------------------------ updates

    def add_keyframe(
        self,
        frame_index: int,
        stamp: float,
        pose_wc: np.ndarray,
        features: Features,
        point_ids: np.ndarray,
        dynamic: np.ndarray,
        create: np.ndarray,
    ) -> KeyFrame:
        """Insert a keyframe observing ``point_ids`` (-1 = none) and create map points for the
        keypoints in the boolean mask ``create`` (they must have depth and no point yet)."""
        kf = KeyFrame(
            id=len(self.keyframes),
            frame_index=frame_index,
            stamp=stamp,
            pose_wc=pose_wc.copy(),
            features=features,
            point_ids=point_ids.copy(),
            dynamic=dynamic.copy(),
        )
        self.keyframes.append(kf)
        observed = np.flatnonzero(kf.point_ids >= 0)
        if len(observed):
            ids = kf.point_ids[observed]
            pts = self.points
            pts.observations.view[ids] += 1
            pts.latest_descriptor.view[ids] = features.descriptors[observed]
            # Mean viewing direction: running average of unit rays from the cameras.
            ray = pts.position.view[ids] - kf.center
            ray /= np.linalg.norm(ray, axis=1, keepdims=True)
            n = pts.observations.view[ids][:, None].astype(np.float64)
            mean = pts.normal.view[ids] * (n - 1) + ray
            pts.normal.view[ids] = mean / np.linalg.norm(mean, axis=1, keepdims=True)
            self._obs_point.extend(ids)
            self._obs_keyframe.extend(np.full(len(ids), kf.id))
        new = np.flatnonzero(create)
        if len(new):
            world = transform(pose_wc, features.points[new])
            ray = world - kf.center
            dist = np.linalg.norm(ray, axis=1)
            level_scale = self.scale_factor ** features.octave[new]
            max_d = dist * level_scale
            ids = np.arange(self.n_points, self.n_points + len(new))
            pts = self.points
            pts.position.extend(world)
            pts.descriptor.extend(features.descriptors[new])
            pts.latest_descriptor.extend(features.descriptors[new])
            pts.normal.extend(ray / dist[:, None])
            pts.max_distance.extend(max_d)
            pts.min_distance.extend(max_d / self.scale_factor ** (self.n_levels - 1))
            pts.visible.extend(np.ones(len(new), np.int32))
            pts.found.extend(np.ones(len(new), np.int32))
            pts.observations.extend(np.ones(len(new), np.int32))
            pts.first_keyframe.extend(np.full(len(new), kf.id, np.int32))
            pts.bad.extend(np.zeros(len(new), bool))
            kf.point_ids[new] = ids
            self._obs_point.extend(ids)
            self._obs_keyframe.extend(np.full(len(new), kf.id))
        return kf

    def cull(self, min_found_ratio: float = 0.25, min_observations: int = 2) -> int:
        """ORB-SLAM2's recent-point culling; returns how many points were removed.

        Points created in the last three keyframes are removed when found in fewer than
        ``min_found_ratio`` of the frames where they should have been visible, or when, two
        keyframes after their creation, fewer than ``min_observations`` keyframes observe them.
        """
        if not self.keyframes or self.n_points == 0:
            return 0
        pts = self.points
        current = self.keyframes[-1].id
        first = pts.first_keyframe.view
        recent = (~pts.bad.view) & (first >= current - 3)
        ratio = pts.found.view / np.maximum(pts.visible.view, 1)
        bad = recent & (
            (ratio < min_found_ratio)
            | ((current - first >= 2) & (pts.observations.view < min_observations))
        )
        pts.bad.view[bad] = True
        removed = int(bad.sum())
        self.culled += removed
        return removed

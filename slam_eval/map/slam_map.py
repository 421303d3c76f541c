"""The tracker's map: keyframes and map points in growable NumPy arrays.

Map points carry what ORB-SLAM2's tracking needs: world position, two descriptors (from the
creating keyframe and the latest one observing the point), mean viewing direction, the distance
range over which ORB can re-detect the point (scale invariance), visible / found counters for
culling, and their keyframe observations (kept as flat ``(point, keyframe, keypoint)`` arrays so
that covisibility counts are single ``np.bincount`` calls).

The back end (:mod:`..mapping.local_mapping`, :mod:`..mapping.loop_closing`) edits the map: it
moves keyframes and points, erases outlier observations (an erased observation stays in the
arrays, marked invalid), culls redundant keyframes and fuses duplicated points. Keyframes form a spanning tree (each one's
``parent`` shared the most points with it when it was inserted); a culled keyframe keeps its pose
relative to its parent, as ORB-SLAM2's ``KeyFrame::SetBadFlag``, so the frames tracked against it
still have a pose once the map moves (:meth:`SlamMap.pose_wc`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..frontend.orb import Features
from ..geometry import invert, transform


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
    parent: int | None = None
    """Spanning-tree parent: the keyframe sharing the most map points at insertion (None for the
    first keyframe)."""
    bad: bool = False
    """Culled as redundant: observes nothing any more; its pose follows ``parent``."""
    pose_in_parent: np.ndarray | None = None
    """For a culled keyframe: ``T_kf,parent`` (4, 4), its pose relative to its parent's camera."""
    inliers: int | None = None
    """Map-point inliers of the tracked frame it was made from (None: the first keyframe)."""

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
        self._obs_keypoint = _Growable((), np.int64)
        self._obs_valid = _Growable((), bool)
        self._erased = 0
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
        if self._erased:
            hit &= self._obs_valid.view
        return np.bincount(self._obs_keyframe.view[hit], minlength=len(self.keyframes)).astype(
            np.int64
        )

    def points_of(self, keyframe_ids: np.ndarray) -> np.ndarray:
        """Sorted ids of the good map points observed by any of ``keyframe_ids``."""
        if len(keyframe_ids) == 0 or self._obs_point.size == 0:
            return np.zeros(0, np.int64)
        marked = np.zeros(len(self.keyframes), bool)
        marked[keyframe_ids] = True
        hit = marked[self._obs_keyframe.view]
        if self._erased:
            hit &= self._obs_valid.view
        ids = np.unique(self._obs_point.view[hit])
        return ids[~self.points.bad.view[ids]]

    def observations_of(self, point_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Valid observations of ``point_ids``: ``(point, keyframe, keypoint)`` index arrays."""
        marked = np.zeros(self.n_points, bool)
        marked[point_ids] = True
        idx = np.flatnonzero(marked[self._obs_point.view] & self._obs_valid.view)
        return (
            self._obs_point.view[idx],
            self._obs_keyframe.view[idx],
            self._obs_keypoint.view[idx],
        )

    def levels(self, keyframe_ids: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
        """Pyramid level of keypoint ``keypoints[i]`` of keyframe ``keyframe_ids[i]``."""
        out = np.zeros(len(keyframe_ids), np.int64)
        for k in np.unique(keyframe_ids):
            sel = keyframe_ids == k
            out[sel] = self.keyframes[int(k)].features.octave[keypoints[sel]]
        return out

    def covisible(self, keyframe_id: int, min_shared: int) -> np.ndarray:
        """Ids of the other good keyframes sharing at least ``min_shared`` good map points with
        ``keyframe_id`` (ORB-SLAM2's covisibility graph edges have weight >= 15)."""
        ids = self.keyframes[keyframe_id].point_ids
        ids = ids[ids >= 0]
        ids = ids[~self.points.bad.view[ids]]
        counts = self.covisibility(ids)
        counts[keyframe_id] = 0
        return np.flatnonzero(counts >= max(min_shared, 1))

    def pose_wc(
        self, keyframe_id: int, poses_wc: dict[int, np.ndarray] | None = None
    ) -> np.ndarray:
        """Camera-to-world pose of a keyframe; a culled one's follows its parent chain.
        ``poses_wc``: the good keyframes' poses to use instead of their current ones."""
        kf = self.keyframes[keyframe_id]
        if not kf.bad:
            return kf.pose_wc if poses_wc is None else poses_wc[keyframe_id]
        assert kf.parent is not None and kf.pose_in_parent is not None
        return self.pose_wc(kf.parent, poses_wc) @ invert(kf.pose_in_parent)

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
        observed = np.flatnonzero(kf.point_ids >= 0)
        if self.keyframes:
            shared = self.covisibility(kf.point_ids[observed])
            kf.parent = int(np.argmax(shared)) if shared.max() > 0 else self.keyframes[-1].id
        self.keyframes.append(kf)
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
            self._record(ids, kf.id, observed)
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
            self._record(ids, kf.id, new)
        return kf

    def _record(self, point_ids: np.ndarray, keyframe_id: int, keypoints: np.ndarray) -> None:
        self._obs_point.extend(point_ids)
        self._obs_keyframe.extend(np.full(len(point_ids), keyframe_id))
        self._obs_keypoint.extend(keypoints)
        self._obs_valid.extend(np.ones(len(point_ids), bool))

    # ------------------------------------------------------------------ back-end edits

    def erase_observations(self, point_ids: np.ndarray, keyframe_ids: np.ndarray) -> int:
        """Erase the valid observations of ``point_ids[i]`` by ``keyframe_ids[i]`` (ORB-SLAM2's
        ``EraseMapPointMatch`` + ``EraseObservation``); a point left with a single observing
        keyframe is marked bad, as ORB-SLAM2 does for stereo / RGB-D points. Returns how many
        observations were erased."""
        if len(point_ids) == 0:
            return 0
        key = point_ids.astype(np.int64) * len(self.keyframes) + keyframe_ids
        obs_key = self._obs_point.view * len(self.keyframes) + self._obs_keyframe.view
        idx = np.flatnonzero(np.isin(obs_key, key) & self._obs_valid.view)
        self._invalidate(idx)
        return len(idx)

    def _invalidate(self, idx: np.ndarray) -> None:
        if len(idx) == 0:
            return
        self._obs_valid.view[idx] = False
        self._erased += len(idx)
        pts = self._obs_point.view[idx]
        for k in np.unique(self._obs_keyframe.view[idx]):
            sel = self._obs_keyframe.view[idx] == k
            self.keyframes[int(k)].point_ids[self._obs_keypoint.view[idx][sel]] = -1
        np.subtract.at(self.points.observations.view, pts, 1)
        self.points.bad.view[pts[self.points.observations.view[pts] <= 1]] = True

    def cull_keyframe(self, keyframe_id: int) -> None:
        """Remove a redundant keyframe: its observations are erased, its pose is kept relative to
        its parent, and its good children are handed to that parent (ORB-SLAM2 re-links them
        among their covisible keyframes; the parent is the simplest valid choice). Culled
        children keep it as their parent: their poses are relative to it, and the chain of
        culled keyframes leads to a good one (ORB-SLAM2's ``SaveTrajectoryTUM`` walks the same
        chain through ``mTcp``)."""
        kf = self.keyframes[keyframe_id]
        if kf.parent is None or kf.bad:
            raise ValueError(f"keyframe {keyframe_id} cannot be culled")
        parent = self.keyframes[kf.parent]
        kf.pose_in_parent = kf.pose_cw @ self.pose_wc(parent.id)
        kf.bad = True
        self._invalidate(np.flatnonzero((self._obs_keyframe.view == kf.id) & self._obs_valid.view))
        for other in self.keyframes:
            if other.parent == kf.id and not other.bad:
                other.parent = kf.parent

    def update_geometry(self, point_ids: np.ndarray) -> None:
        """Mean viewing direction and scale-invariance distances of moved points, from their
        valid observations (ORB-SLAM2's ``UpdateNormalAndDepth``; distances from the keyframe
        that created the point while it still observes it)."""
        point, keyframe, keypoint = self.observations_of(point_ids)
        if len(point) == 0:
            return
        pts = self.points
        centers = np.stack([self.keyframes[int(k)].center for k in range(len(self.keyframes))])
        ray = pts.position.view[point] - centers[keyframe]
        dist = np.linalg.norm(ray, axis=1)
        total = np.zeros((self.n_points, 3))
        np.add.at(total, point, ray / np.maximum(dist, 1e-12)[:, None])
        ids = np.unique(point)
        norm = np.linalg.norm(total[ids], axis=1, keepdims=True)
        pts.normal.view[ids] = total[ids] / np.maximum(norm, 1e-12)
        own = keyframe == pts.first_keyframe.view[point]
        octave = self.levels(keyframe[own], keypoint[own])
        max_d = dist[own] * self.scale_factor**octave
        pts.max_distance.view[point[own]] = max_d
        pts.min_distance.view[point[own]] = max_d / self.scale_factor ** (self.n_levels - 1)

    def add_observation(self, point_id: int, keyframe_id: int, keypoint: int) -> None:
        """Keyframe ``keyframe_id``'s keypoint ``keypoint`` (without a map point) sees ``point_id``."""
        kf = self.keyframes[keyframe_id]
        kf.point_ids[keypoint] = point_id
        self.points.observations.view[point_id] += 1
        self._record(np.array([point_id]), keyframe_id, np.array([keypoint]))

    def replace_point(self, old: int, new: int) -> None:
        """Fuse duplicated points: every observation of ``old`` becomes one of ``new`` (dropped
        where the keyframe already sees ``new``), and ``old`` is marked bad (ORB-SLAM2's
        ``MapPoint::Replace``)."""
        if old == new:
            return
        idx = np.flatnonzero((self._obs_point.view == old) & self._obs_valid.view)
        seen = self._obs_keyframe.view[(self._obs_point.view == new) & self._obs_valid.view]
        pts = self.points
        for i in idx:
            k = int(self._obs_keyframe.view[i])
            kp = int(self._obs_keypoint.view[i])
            if k in seen:
                self._obs_valid.view[i] = False
                self._erased += 1
                self.keyframes[k].point_ids[kp] = -1
            else:
                self._obs_point.view[i] = new
                self.keyframes[k].point_ids[kp] = new
                pts.observations.view[new] += 1
        pts.visible.view[new] += pts.visible.view[old]
        pts.found.view[new] += pts.found.view[old]
        pts.observations.view[old] = 0
        pts.bad.view[old] = True

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

"""Local mapping after each new keyframe: local bundle adjustment and keyframe culling, as
ORB-SLAM2's ``LocalMapping`` (``Optimizer::LocalBundleAdjustment``, ``KeyFrameCulling``; by
default ORB-SLAM3's single optimisation pass), with GTSAM factor graphs and Levenberg–Marquardt.

Local bundle adjustment of a new keyframe ``K`` (free: ``K``, its covisible keyframes and
their points; fixed: the keyframes that also observe those points, and keyframe 0) is
:class:`~..optim.local_ba.BundleAdjuster`'s, which describes its factors, noise and passes.

Schedule (``min_interval_s``, ORB-SLAM2's queue of new keyframes): the mapper runs local BA only
when no newer keyframe waits, and a new keyframe interrupts it. Here the main thread runs it, so
that behaviour is modelled on the camera clock: after a local BA the mapper counts as busy for
``min_interval_s`` seconds of frame stamps; a keyframe made meanwhile waits, a newer one replaces
it (the older one's BA is skipped, as ORB-SLAM2 optimises only the newest keyframe of its queue),
and the waiting keyframe is adjusted (with culling) on the first frame after the busy time. 0 (the
default) adjusts every keyframe at once.

Keyframe culling: a covisible keyframe of ``K`` (never keyframe 0) is removed when more than
``redundancy`` (90%) of its close map points (those of keypoints with depth) are seen by at least
``redundant_observers`` (3) other keyframes at the same or a finer pyramid level (± one).

The optimisation runs in the main thread between frames, its cost bounded by the iteration
counts: GTSAM's Python binding holds the GIL while it optimises, so a background thread would not
overlap it with tracking, and in the main thread the results do not depend on timing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from uss_slam.core.schema import check_fields, ranged

from ..map.slam_map import SlamMap
from ..optim.local_ba import Adjustment, BundleAdjuster


@dataclass(frozen=True)
class LocalMappingConfig:
    """Local bundle adjustment and keyframe culling (defaults: ORB-SLAM2's)."""

    depth_noise: float | None = ranged(None, min=0)
    """k of the depth noise ``σ_z = k·z²`` the stereo observations model, metres⁻¹ (module
    docstring); 0 = ORB-SLAM2's independent ``(u, v, u_r)`` of equal sigma; None (the default)
    = the camera's: the ``depth_noise`` its ``intrinsics.yaml`` declares (the synthetic target
    style: 0.0019), else ORB-SLAM2's model (a real Kinect, whose depth is far from ``k·z²``'s
    precision: :func:`depth_noise_of`)."""
    covisibility: int = ranged(15, min=1)
    """Keyframes sharing at least this many map points with the new keyframe are optimised."""
    max_keyframes: int = ranged(0, min=0)
    """At most this many covisible keyframes are optimised, those sharing the most points first
    (the others are fixed); 0 = all, as ORB-SLAM2."""
    first_iterations: int = ranged(2, min=1)
    """LM iterations with the Huber kernel (2 since 2026-12-07, chosen by the rule in
    docs/results/slam.md, "two convergence cuts for speed"; the next keyframe's BA goes on from
    where this one stopped); ORB-SLAM3's single pass: 10 (the default before); ORB-SLAM2: 5,
    then a second pass."""
    second_iterations: int = ranged(0, min=0)
    """LM iterations after leaving the outliers out, without kernel (0 = none, ORB-SLAM3;
    ORB-SLAM2: 10, skipped when a new keyframe interrupts it; the default's measurements:
    docs/results/slam.md)."""
    culling: bool = True
    """Remove redundant keyframes after each local bundle adjustment."""
    redundancy: float = ranged(0.9, gt=0, max=1, needs="culling")
    """A keyframe is redundant when more than this fraction of its close points are seen by
    ``redundant_observers`` other keyframes (ORB-SLAM2: 0.9)."""
    redundant_observers: int = ranged(3, min=1, needs="culling")
    doubt_inliers: int = ranged(0, min=0)
    """A new keyframe tracked with fewer map-point inliers than this is doubted: its local BA
    frees it alone (its covisible keyframes stay fixed), so the map corrects its pose and it
    moves no other keyframe; 0 = off (ORB-SLAM2 frees every covisible keyframe)."""

    min_interval_s: float = ranged(0.0, min=0)
    """Camera seconds (frame stamps) the mapper counts as busy after a local BA: a keyframe made
    meanwhile waits for the end of that time and a newer one replaces it (module docstring,
    "Schedule"); 0 = every keyframe adjusted at once."""

    def __post_init__(self) -> None:
        check_fields(self)


def depth_noise_of(config: LocalMappingConfig, camera_noise: float | None) -> tuple[float, str]:
    """The ``k`` local BA models and where it came from: the setting when given, else the
    camera's declared noise, else ORB-SLAM2's model (0)."""
    if config.depth_noise is not None:
        return float(config.depth_noise), "slam.local_ba_params.depth_noise"
    if camera_noise is not None:
        return float(camera_noise), "the camera's intrinsics.yaml"
    return 0.0, "ORB-SLAM2's model (the camera declares no depth noise)"


@dataclass
class LocalMappingStats:
    """Totals over a run: ``runs`` local bundle adjustments, their mean ``wall_ms``, keyframes
    ``culled``, outlier ``observations_erased``; keyframes ``deferred`` (made while the mapper was
    busy, ``min_interval_s``) and ``skipped`` (of those, replaced by a newer one before their
    BA); ``readjusted``: local BAs run again around a keyframe whose late mask took points out
    (:meth:`LocalMapping.readjust`, not in ``runs`` nor ``wall_ms``)."""

    runs: int = 0
    wall_s: float = 0.0
    culled: int = 0
    observations_erased: int = 0
    optimised_keyframes: int = 0
    optimised_points: int = 0
    deferred: int = 0
    skipped: int = 0
    readjusted: int = 0

    def as_dict(self) -> dict[str, float | int]:
        return {
            "runs": self.runs,
            "wall_ms": 1000.0 * self.wall_s / max(self.runs, 1),
            "keyframes_culled": self.culled,
            "observations_erased": self.observations_erased,
            "mean_free_keyframes": self.optimised_keyframes / max(self.runs, 1),
            "mean_points": self.optimised_points / max(self.runs, 1),
            "keyframes_deferred": self.deferred,
            "keyframes_skipped": self.skipped,
            "readjusted": self.readjusted,
        }


class LocalMapping:
    """Runs local bundle adjustment and keyframe culling on each new keyframe of a map."""

    def __init__(self, config: LocalMappingConfig, adjuster: BundleAdjuster) -> None:
        self.config = config
        self.adjuster = adjuster
        self.stats = LocalMappingStats()
        self.waiting: int | None = None
        """The keyframe whose BA waits for the end of the busy time (``min_interval_s``)."""
        self.busy_until = -np.inf
        """Frame stamp (s) until which the mapper counts as busy after its last local BA."""

    def keyframe(self, slam_map: SlamMap, keyframe_id: int, stamp: float) -> bool:
        """A new keyframe made at ``stamp`` (s): adjusted now when the mapper is free, else it
        waits (replacing a waiting one). Returns whether the map changed."""
        if self.waiting is not None:
            self.stats.skipped += 1
            self.waiting = None
        if stamp < self.busy_until:
            self.stats.deferred += 1
            self.waiting = keyframe_id
            return False
        self.run(slam_map, keyframe_id, stamp)
        return True

    def frame(self, slam_map: SlamMap, stamp: float) -> bool:
        """A frame at ``stamp`` (s) without a new keyframe: the waiting keyframe is adjusted
        when the busy time is over (and it was not culled meanwhile). Returns whether the map
        changed."""
        if self.waiting is None or stamp < self.busy_until:
            return False
        keyframe_id, self.waiting = self.waiting, None
        if slam_map.keyframes[keyframe_id].bad:
            self.stats.skipped += 1
            return False
        self.run(slam_map, keyframe_id, stamp)
        return True

    def run(self, slam_map: SlamMap, keyframe_id: int, stamp: float) -> None:
        """:meth:`process` at ``stamp``, and the busy time that follows."""
        self.process(slam_map, keyframe_id)
        self.busy_until = stamp + self.config.min_interval_s

    def local_keyframes(self, slam_map: SlamMap, keyframe_id: int) -> np.ndarray:
        """The new keyframe and its covisible keyframes (most shared points first if capped);
        a :meth:`doubted` keyframe alone."""
        cfg = self.config
        if self.doubted(slam_map, keyframe_id):
            return np.array([keyframe_id], np.int64)
        ids = slam_map.keyframes[keyframe_id].point_ids
        ids = ids[ids >= 0]
        counts = slam_map.covisibility(ids[~slam_map.points.bad.view[ids]])
        counts[keyframe_id] = 0
        order = np.argsort(-counts, kind="stable")
        order = order[counts[order] >= cfg.covisibility]
        if cfg.max_keyframes:
            order = order[: cfg.max_keyframes]
        return np.union1d(order, [keyframe_id]).astype(np.int64)

    def doubted(self, slam_map: SlamMap, keyframe_id: int) -> bool:
        """Was the keyframe tracked with fewer map-point inliers than ``doubt_inliers``?"""
        inliers = slam_map.keyframes[keyframe_id].inliers
        return inliers is not None and inliers < self.config.doubt_inliers

    def process(self, slam_map: SlamMap, keyframe_id: int) -> tuple[Adjustment, list[int]]:
        """Local BA around ``keyframe_id``, then culling of its redundant covisible keyframes;
        returns the adjustment and the culled keyframe ids."""
        start = time.perf_counter()
        local = self.local_keyframes(slam_map, keyframe_id)
        points = slam_map.points_of(local)
        adjustment = self.adjuster.adjust(
            slam_map,
            local,
            points,
            self.config.first_iterations,
            self.config.second_iterations,
        )
        culled = self.cull(slam_map, keyframe_id) if self.config.culling else []
        s = self.stats
        s.runs += 1
        s.wall_s += time.perf_counter() - start
        s.culled += len(culled)
        s.observations_erased += adjustment.outliers
        s.optimised_keyframes += len(adjustment.free)
        s.optimised_points += len(points)
        return adjustment, culled

    def readjust(
        self, slam_map: SlamMap, keyframe_id: int, also: np.ndarray | None = None
    ) -> Adjustment:
        """Local BA around ``keyframe_id`` again, without culling (its mask came late and took
        map points out: the keyframes those points pulled are adjusted without them), with the
        keyframes ``also`` free too; counted as ``readjusted``."""
        local = self.local_keyframes(slam_map, keyframe_id)
        if also is not None and len(also):
            local = np.union1d(local, also).astype(np.int64)
        points = slam_map.points_of(local)
        adjustment = self.adjuster.adjust(
            slam_map, local, points, self.config.first_iterations, self.config.second_iterations
        )
        self.stats.readjusted += 1
        self.stats.observations_erased += adjustment.outliers
        return adjustment

    def cull(self, slam_map: SlamMap, keyframe_id: int) -> list[int]:
        """ORB-SLAM2's ``KeyFrameCulling`` over the covisible keyframes of ``keyframe_id``."""
        culled = []
        for c in slam_map.covisible(keyframe_id, self.config.covisibility):
            c = int(c)
            if c == 0 or slam_map.keyframes[c].bad:
                continue
            if self.redundant(slam_map, c):
                slam_map.cull_keyframe(c)
                culled.append(c)
        return culled

    def redundant(self, slam_map: SlamMap, keyframe_id: int) -> bool:
        """More than ``redundancy`` of the keyframe's close good points are seen by at least
        ``redundant_observers`` other keyframes at a level no coarser than its own + 1."""
        kf = slam_map.keyframes[keyframe_id]
        pts = slam_map.points
        own = np.flatnonzero(kf.point_ids >= 0)
        own = own[~pts.bad.view[kf.point_ids[own]] & (kf.features.depth[own] > 0)]
        if len(own) == 0:
            return False
        point_ids = kf.point_ids[own]
        own_level = np.full(slam_map.n_points, -1, np.int64)
        own_level[point_ids] = kf.features.octave[own]
        many = point_ids[pts.observations.view[point_ids] > self.config.redundant_observers]
        point, other, keypoint = slam_map.observations_of(many)
        keep = other != keyframe_id
        point, other, keypoint = point[keep], other[keep], keypoint[keep]
        level = slam_map.levels(other, keypoint)
        fine = level <= own_level[point] + 1
        observers = np.bincount(point[fine], minlength=slam_map.n_points)
        n_redundant = int((observers[point_ids] >= self.config.redundant_observers).sum())
        return n_redundant > self.config.redundancy * len(point_ids)

"""What a late mask of the semantic thread (``segment=thread``) may still correct in the map,
beyond its own keyframe (:meth:`~.frame_loop.FrameLoop.refine_past`, over the :class:`PastFrame`
records the loop keeps), and the end-of-run pass.

- :func:`erase_carried` (``slam.mask_refits_keyframes``): the keyframes made since the previous
  mask's keyframe were tracked and mapped with a stale carried mask. A newer mask, carried back
  to each by its map pose, shows where the people were there: the observations those keyframes
  made through a keypoint inside it are erased (the points stay, for the keyframes that saw them
  elsewhere), so that local BA, run again with those keyframes free, moves them without the
  people's pull. ``slam.mask_refit_min_observations`` leaves out a keyframe that would keep
  fewer observations than that.
- :func:`adjust_all` (``slam.final_ba``): once the last frame is tracked (with the semantic
  thread, once the masks still in flight are delivered), one bundle adjustment of every good
  keyframe and map point (keyframe 0 fixed), as ORB-SLAM2's global BA after a loop closure: the
  keyframes that left every local window keep the error they had when they left it otherwise.
  An end-of-run step, not an online one: the trajectory composed after it is the final map's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..filters.base import values_at
from ..frontend.orb import Features
from ..geometry import invert
from ..map.slam_map import SlamMap
from ..optim.local_ba import Adjustment, BundleAdjuster
from ..tracking.tracker import Tracker
from .semantic_thread import CarriedMask


@dataclass
class PastFrame:
    """A tracked frame a late mask may still correct (``slam.mask_refines_past``): its ``row``
    in the loop's ``stamps`` / ``poses`` / ``anchors``, its ``stamp`` (s), keypoints and the map
    point each was matched to when tracked (``matched`` (N,), -1 none)."""

    row: int
    stamp: float
    features: Features
    matched: np.ndarray


PAST_FRAMES = 300
"""``mask_refines_past`` keeps at most this many past frames (10 s at 30 Hz)."""


def refine_frames(
    slam_map: SlamMap,
    tracker: Tracker,
    past: list[PastFrame],
    poses: list[np.ndarray],
    anchors: list[tuple[int, np.ndarray]] | None,
    carried: CarriedMask,
    region_of: Callable[[np.ndarray], np.ndarray | None] | None,
) -> int:
    """Each frame of ``past`` tracked on a map point now bad (with ``region_of``, or on a
    keypoint inside ``region_of(labels)`` of the keyframe mask ``carried`` to the frame by its
    pose) gets its pose refined on its other matches in the map as it is now (kept where enough
    inliers remain, :meth:`~..tracking.tracker.Tracker.refine_without`), in ``poses`` (the
    loop's camera-to-world poses as tracked) and, with the back end, put back on its reference
    keyframe in ``anchors`` (None without one); returns how many were refined."""
    bad = slam_map.points.bad.view
    source = carried.source_pose(slam_map)
    refined_frames = 0
    for frame in past:
        ids = frame.matched
        used = ids >= 0
        pose = poses[frame.row]
        if anchors is not None:
            k, rel = anchors[frame.row]
            pose = slam_map.pose_wc(k) @ invert(rel)
        drop = np.zeros(len(ids), bool)
        drop[used] = bad[ids[used]]
        if region_of is not None:
            labels = carried.labels_at(invert(pose) @ source)
            region = region_of(labels)
            if region is not None:
                drop |= used & values_at(region, frame.features.xy)
        if not (drop & used).any():
            continue
        refined, _ = tracker.refine_without(pose, frame.features, ids, drop)
        if refined is None:
            continue
        poses[frame.row] = refined
        if anchors is not None:
            anchors[frame.row] = (k, invert(refined) @ slam_map.pose_wc(k))
        refined_frames += 1
    return refined_frames


FINAL_BA = ("none", "thread", "always")
"""``slam.final_ba``: with which schedules the end-of-run bundle adjustment runs (``thread``:
``segment=thread`` only; ``always``: every schedule, for the reference cells)."""


def since_previous(slam_map: SlamMap, kf_id: int, previous: int | None) -> list[int]:
    """The good keyframes other than ``kf_id`` made after ``previous`` (the keyframe of the mask
    delivered before; None: none yet, no keyframe is taken)."""
    if previous is None:
        return []
    return [kf.id for kf in slam_map.keyframes[previous + 1 :] if not kf.bad and kf.id != kf_id]


def erase_carried(
    slam_map: SlamMap,
    carried: CarriedMask,
    targets: list[int],
    region_of: Callable[[np.ndarray], np.ndarray | None],
    floor: int = 0,
) -> tuple[int, list[int]]:
    """Carry ``carried`` (keyframe ``carried.kf_id``'s delivered mask) to each keyframe of
    ``targets`` by the map poses now (:meth:`~.semantic_thread.CarriedMask.labels_at`); its
    keypoints inside ``region_of(labels)`` ((H, W) bool dynamic pixels of the carried labels,
    None: none) are flagged dynamic and their observations of map points erased
    (:meth:`~..map.slam_map.SlamMap.erase_observations`: a point left with one keyframe turns
    bad). A keyframe that would keep fewer than ``floor`` observations of good map points
    outside the region is left as it is (0: none is): a mask that takes most of a keyframe's
    points away is as likely carried there by a pose the people pulled, and a keyframe left
    with few observations is moved freely by local BA. Returns how many observations were
    erased and the targets not left under the floor (the keyframes local BA may free)."""
    erased, kept = 0, []
    pose_kf = carried.source_pose(slam_map)
    for target in targets:
        kf = slam_map.keyframes[target]
        region = region_of(carried.labels_at(invert(slam_map.pose_wc(target)) @ pose_kf))
        if region is None or not region.any():
            kept.append(target)
            continue
        inside = values_at(region, kf.features.xy)
        if floor > 0 and _left_outside(slam_map, kf.point_ids, inside) < floor:
            continue
        kept.append(target)
        kf.dynamic = kf.dynamic | inside
        ids = kf.point_ids[inside & (kf.point_ids >= 0)]
        erased += slam_map.erase_observations(ids, np.full(len(ids), target, np.int64))
    return erased, kept


def _left_outside(slam_map: SlamMap, point_ids: np.ndarray, inside: np.ndarray) -> int:
    """How many of a keyframe's observations (``point_ids``, (N,), -1: none) of good map points
    lie outside ``inside`` ((N,) bool)."""
    ids = point_ids[~inside & (point_ids >= 0)]
    return int((~slam_map.points.bad.view[ids]).sum())


def final_ba_runs(final_ba: str, segment: str) -> bool:
    """Does ``slam.final_ba`` (:data:`FINAL_BA`) run the end-of-run pass with ``segment``?"""
    if final_ba not in FINAL_BA:
        raise ValueError(f"final_ba: expected one of {FINAL_BA}, got {final_ba!r}")
    return final_ba == "always" or (final_ba == "thread" and segment == "thread")


FINAL_BA_ITERATIONS = 10
"""Levenberg–Marquardt iterations of the end-of-run bundle adjustment (ORB-SLAM3's single pass;
local BA's own count, ``slam.local_ba_params.first_iterations``, has been 2 since the evening of
2026-12-07)."""


def adjust_all(
    slam_map: SlamMap, adjuster: BundleAdjuster, iterations: int = FINAL_BA_ITERATIONS
) -> Adjustment:
    """One bundle adjustment of every good keyframe (keyframe 0 fixed, the gauge) and every good
    map point they observe, ``iterations`` Levenberg–Marquardt iterations with the Huber kernel
    (local BA's single pass); outliers erased as local BA does."""
    free = np.array([kf.id for kf in slam_map.keyframes if not kf.bad], np.int64)
    return adjuster.adjust(slam_map, free, slam_map.points_of(free), iterations, 0)

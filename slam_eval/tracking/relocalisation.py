"""Relocalisation when tracking is lost, as ORB-SLAM2's ``Relocalization`` without its bag of
words, on the descriptor matching of a frame to a keyframe's map points
(:func:`~..matching.keyframe.match_keyframe`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..frontend.orb import Features
from ..map.slam_map import SlamMap
from ..matching.keyframe import match_keyframe
from ..matching.sampling import PoseSampler
from .config import TrackerConfig

LocalMapTracker = Callable[
    [np.ndarray, np.ndarray, Features, np.ndarray],
    tuple[np.ndarray | None, np.ndarray | None],
]
"""``(local map point ids, pose_cw, features, static) -> (pose_cw, matched)``: local-map
tracking from a pose (``(None, None)`` when it fails)."""


def relocalise(
    cfg: TrackerConfig,
    slam_map: SlamMap,
    sampler: PoseSampler,
    track_local_map: LocalMapTracker,
    features: Features,
    static: np.ndarray,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """ORB-SLAM2's relocalisation without its bag of words: every keyframe of the map is a
    candidate, scored by how many of the frame's static descriptors match its map points
    (ratio test); the ``reloc_keyframes`` best are tried in that order (PnP-RANSAC, then
    local-map tracking, ``reloc_min_inliers`` needed). ORB-SLAM2 likewise queries its whole
    keyframe database: after a long occlusion the keyframes near the last known pose may be
    the ones taken while the view was blocked, holding few of the points now in view.
    Returns ``(pose_cw, matched map point per keypoint)`` or ``(None, None)``."""
    kfs = slam_map.keyframes
    if not kfs or static.sum() < cfg.min_inliers:
        return None, None
    query = np.flatnonzero(static)
    scored: list[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]] = []
    for k, kf in enumerate(kfs):
        found = match_keyframe(
            slam_map,
            features,
            query,
            kf,
            cfg.reloc_ratio,
            cfg.reloc_max_hamming,
            cfg.min_inliers,
            cfg.check_orientation,
        )
        if found is not None and len(found[0]) >= cfg.min_matches:
            scored.append((len(found[0]), k, *found))
    # Most matches first; ties: the latest keyframe first.
    scored.sort(key=lambda c: (-c[0], -c[1]))
    for _, k, kp, pid, distance in scored[: cfg.reloc_keyframes]:
        found = sampler.pnp_global(slam_map.points.position.view[pid], features, kp, distance)
        if found is None:
            continue
        pose_cw = found[0]
        local = slam_map.points_of(
            np.union1d(
                [k],
                np.argsort(-slam_map.covisibility(pid))[: cfg.local_keyframes],
            ).astype(np.int64)
        )
        pose2, matched = track_local_map(local, pose_cw, features, static)
        if pose2 is not None and (matched >= 0).sum() >= cfg.reloc_min_inliers:
            return pose2, matched
    return None, None

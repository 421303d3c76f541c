"""Relocalisation when tracking is lost, as ORB-SLAM2's ``Relocalization`` without its bag of
words, and the descriptor matching of a frame to a keyframe's map points it is built on (also
ORB-SLAM2's ``TrackReferenceKeyFrame`` and the loop closer's candidate search).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from ..frontend.orb import Features
from ..map.slam_map import KeyFrame, SlamMap
from .config import TrackerConfig
from .projection import rotation_consistent
from .sampling import PoseSampler

LocalMapTracker = Callable[
    [np.ndarray, np.ndarray, Features, np.ndarray],
    tuple[np.ndarray | None, np.ndarray | None],
]
"""``(local map point ids, pose_cw, features, static) -> (pose_cw, matched)``: local-map
tracking from a pose (``(None, None)`` when it fails)."""


def match_keyframe(
    slam_map: SlamMap,
    features: Features,
    query: np.ndarray,
    kf: KeyFrame,
    ratio: float,
    max_hamming: int,
    min_points: int,
    check_orientation: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Keypoints ``query`` of ``features`` matched to the good map points of a keyframe by
    descriptor (nearest neighbour in Hamming distance among the keyframe's keypoints that
    hold one, ratio test, at most ``max_hamming``), one keypoint per map point: ``(keypoint
    indices, map point ids, distances)``; None when the keyframe holds fewer than
    ``min_points`` good points or there is nothing to query (a frame without keypoints).
    ``check_orientation``: keep only the matches of a consistent image rotation
    (:func:`.projection.rotation_consistent`, as ORB-SLAM2's ``SearchByBoW``)."""
    ids = kf.point_ids
    usable = np.flatnonzero((ids >= 0) & ~slam_map.points.bad.view[np.maximum(ids, 0)])
    if len(usable) < min_points or len(query) == 0:
        return None
    dist, nearest = cv2.batchDistance(
        features.descriptors[query],
        kf.features.descriptors[usable],
        cv2.CV_32S,
        normType=cv2.NORM_HAMMING,
        K=2,
    )
    good = (dist[:, 0] < ratio * dist[:, 1]) & (dist[:, 0] <= max_hamming)
    kp = query[np.flatnonzero(good)]
    pid = ids[usable[nearest[good, 0]]]
    if check_orientation:
        keep = rotation_consistent(kf.features.angle[usable[nearest[good, 0]]], features.angle[kp])
        good[np.flatnonzero(good)[~keep]] = False
        kp, pid = kp[keep], pid[keep]
    # Keep one keypoint per map point (the first, i.e. arbitrary but deterministic).
    _, first = np.unique(pid, return_index=True)
    return kp[first], pid[first], dist[good, 0][first]


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

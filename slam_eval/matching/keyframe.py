"""Descriptor matching of a frame to the map points a keyframe observes, as ORB-SLAM2's
``SearchByBoW`` without its bag of words (every keyframe keypoint is a candidate): used by
tracking's ``TrackReferenceKeyFrame`` and relocalisation and by loop closing's candidate search.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..frontend.orb import Features
from ..map.slam_map import KeyFrame, SlamMap
from .projection import rotation_consistent


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

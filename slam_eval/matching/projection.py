"""Matching by projection, ORB-SLAM2's ``SearchByProjection``: points projected with a pose
and matched to the keypoints near their projection (:func:`~.descriptor.guided_match`),
map points with the frustum, distance and viewing-angle tests of ``MapPoint::isInFrustum``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..frontend.orb import Features
from ..geometry import invert, project, transform
from ..map.slam_map import SlamMap
from .descriptor import Matches, guided_match

ROTATION_BINS = 30
"""Bins of the rotation histogram (ORB-SLAM2's ``HISTO_LENGTH``)."""


@dataclass(frozen=True)
class MatchThresholds:
    """What a projection match must pass (ORB-SLAM2's ``ORBmatcher`` settings): the best
    keypoint within ``max_hamming`` bits and below ``ratio`` × the second best's distance, and
    with ``check_orientation`` a consistent image rotation (:func:`rotation_consistent`)."""

    max_hamming: int = 100
    ratio: float = 0.8
    check_orientation: bool = True


def rotation_consistent(reference_angle: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """ORB-SLAM2's orientation check (``mbCheckOrientation``, ``ComputeThreeMaxima``): the
    keypoint-angle changes ``reference_angle - angle`` (degrees) of a set of matches are binned
    in a 30-bin histogram, and only the matches in the three fullest bins are kept (the second
    and third only with at least 10% of the fullest's count). Between two views the image turns
    by one angle for every true match; wrong matches spread over all bins. Returns ``(M,)`` bool."""
    if len(angle) == 0:
        return np.zeros(0, bool)
    turn = np.mod(np.asarray(reference_angle, np.float64) - angle, 360.0)
    bins = np.minimum((turn * ROTATION_BINS / 360.0).astype(np.int64), ROTATION_BINS - 1)
    counts = np.bincount(bins, minlength=ROTATION_BINS)
    order = np.argsort(-counts, kind="stable")[:3]
    keep = order[counts[order] >= max(0.1 * counts[order[0]], 1)]
    return np.isin(bins, keep)


class ProjectionMatcher:
    """Projection matching into frames of one camera: ``k`` (3, 3), ``size`` ``(width, height)``
    px, ``scales`` (levels,) each pyramid level's scale factor; map points from ``slam_map``."""

    def __init__(
        self,
        config: MatchThresholds,
        slam_map: SlamMap,
        k: np.ndarray,
        size: tuple[int, int],
        scales: np.ndarray,
    ) -> None:
        self.config = config
        self.map = slam_map
        self.k = k
        self.size = size
        self.scales = scales

    def project(self, point_ids: np.ndarray, pose_cw: np.ndarray):
        """Frustum test of map points: ``(ids, uv, level)`` of those the camera should see."""
        pts = self.map.points
        world = pts.position.view[point_ids]
        cam = transform(pose_cw, world)
        z = cam[:, 2]
        uv = project(self.k, cam)
        w, h = self.size
        center = invert(pose_cw)[:3, 3]
        ray = world - center
        dist = np.linalg.norm(ray, axis=1)
        cos_view = (ray * pts.normal.view[point_ids]).sum(axis=1) / np.maximum(dist, 1e-9)
        ok = (
            (z > 0.05)
            & (uv[:, 0] >= 0)
            & (uv[:, 0] < w)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] < h)
            & (dist >= 0.8 * pts.min_distance.view[point_ids])
            & (dist <= 1.2 * pts.max_distance.view[point_ids])
            & (cos_view >= 0.5)
        )
        ids = point_ids[ok]
        return ids, uv[ok], self.map.predict_level(ids, dist[ok]), cos_view[ok]

    def match_map_points(
        self,
        point_ids: np.ndarray,
        pose_cw: np.ndarray,
        features: Features,
        available: np.ndarray,
        radius: float,
        local: bool = False,
    ) -> tuple[np.ndarray, Matches]:
        """ORB-SLAM2's ``SearchByProjection``: the map points ``point_ids`` in the view of
        ``pose_cw`` (frustum, distance and viewing-angle tests) matched to the ``available``
        keypoints of ``features`` within ``radius`` × the predicted level's scale, px. Returns
        the projected ids and the matches (``query`` indexes those ids). ``local``: count the
        points as visible (local-map tracking) and narrow the window for frontal views."""
        ids, uv, level, cos_view = self.project(point_ids, pose_cw)
        r = radius * self.scales[level]
        if local:
            self.map.points.visible.view[ids] += 1
            # ORB-SLAM2 narrows the local-map window for near-frontal views (RadiusByViewingCos).
            r = r * np.where(cos_view > 0.998, 0.625, 1.0)
        pts = self.map.points
        descriptors = (pts.descriptor.view[ids], pts.latest_descriptor.view[ids])
        return ids, self.guided(uv, r, level, descriptors, features, available)

    def guided(self, uv, radius, level, descriptors, features: Features, available) -> Matches:
        """:func:`guided_match` of projections to ``features`` with the tracker's limits."""
        return guided_match(
            uv,
            radius,
            level,
            descriptors,
            features.uv,
            features.octave,
            features.descriptors,
            available,
            self.size,
            max_distance=self.config.max_hamming,
            ratio=self.config.ratio,
        )

    def match_points(self, world, desc, level, pose_cw, features, available, radius, angle=None):
        """Points ``world`` (with their descriptors and the level they were seen at) projected
        with ``pose_cw`` and matched to the ``available`` keypoints within ``radius`` × their
        level's scale (ORB-SLAM2's frame-to-frame ``SearchByProjection``): ``(query, keypoint)``
        index arrays. ``angle`` (M,) degrees, the points' keypoint angles in the view they come
        from: the matches are checked for a consistent image rotation
        (:func:`rotation_consistent`, ``check_orientation``)."""
        cam = transform(pose_cw, world)
        w, h = self.size
        front = cam[:, 2] > 1e-6
        uv = project(self.k, np.where(front[:, None], cam, 1.0))
        inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        q = np.flatnonzero(inside)
        radii = radius * self.scales[level[q]]
        m = self.guided(uv[q], radii, level[q], (desc[q],), features, available)
        query, kp = q[m.query], m.keypoint
        if angle is not None and self.config.check_orientation:
            keep = rotation_consistent(angle[query], features.angle[kp])
            query, kp = query[keep], kp[keep]
        return query, kp

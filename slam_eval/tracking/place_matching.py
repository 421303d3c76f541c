"""What loop closing asks the tracker for (the ``PlaceMatcher`` interface of
:mod:`..mapping.loop_closing`): keyframe matching, projection matching and the pose solvers on
the tracker's map, so that the back end never imports the tracking loop."""

from __future__ import annotations

import numpy as np

from ..frontend.orb import Features
from ..map.slam_map import KeyFrame, SlamMap
from ..matching.descriptor import Matches
from ..matching.keyframe import match_keyframe
from ..matching.projection import ProjectionMatcher
from ..matching.sampling import PoseSampler


class PlaceMatching:
    """The loop-closing services of :class:`~.tracker.Tracker` (a base class of it), over its
    ``map``, ``projection`` and ``sampler``."""

    map: SlamMap
    projection: ProjectionMatcher
    sampler: PoseSampler

    def match_keyframe(
        self,
        features: Features,
        query: np.ndarray,
        kf: KeyFrame,
        ratio: float,
        max_hamming: int,
        min_points: int,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """:func:`~..matching.keyframe.match_keyframe` on this tracker's map."""
        return match_keyframe(self.map, features, query, kf, ratio, max_hamming, min_points)

    def match_projected(
        self,
        point_ids: np.ndarray,
        pose_cw: np.ndarray,
        features: Features,
        available: np.ndarray,
        radius: float,
        local: bool = False,
    ) -> tuple[np.ndarray, Matches]:
        """:meth:`.ProjectionMatcher.match_map_points`: ``(projected ids, matches)``."""
        return self.projection.match_map_points(
            point_ids, pose_cw, features, available, radius, local
        )

    def pnp_global(
        self, world: np.ndarray, features: Features, kp: np.ndarray, distance: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`.PoseSampler.pnp_global`: a pose without a prior."""
        return self.sampler.pnp_global(world, features, kp, distance)

    def refine_pose(
        self, world: np.ndarray, features: Features, kp: np.ndarray, pose_cw: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`.PoseSampler.refine_pose`: ``(pose_cw, inlier mask)``."""
        return self.sampler.refine_pose(world, features, kp, pose_cw)

"""The map products of one run, fed each new keyframe as it is inserted and built at the end:
the semantic point cloud (:mod:`.semantic_map`) and, with ``octomap``, the semantic OctoMap
(:mod:`.octomap`).

With the back end on (``placed_at_end``) a keyframe may still move after it is inserted: its
cloud is kept in its own camera frame and placed at the keyframe's final pose at the end;
without it, the cloud is added at the keyframe's pose now. The OctoMap always takes every
keyframe at its final pose.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..frontend.orb import OrbExtractor
from ..map.slam_map import KeyFrame
from ..sequence import Frame
from .octomap import OctoMapBuilder, SemanticOctoMap
from .semantic_map import MapConfig, PointCloud, SemanticMapBuilder, merge_clouds


class MapProducts:
    """Collects keyframes for the point cloud and the OctoMap of one run."""

    def __init__(self, config: MapConfig, extractor: OrbExtractor, placed_at_end: bool) -> None:
        self.config = config
        self.extractor = extractor
        self.placed_at_end = placed_at_end
        self.cloud = SemanticMapBuilder(config, extractor)
        self.octo = OctoMapBuilder(config, extractor) if config.octomap else None
        self.keyframe_clouds: list[tuple[int, PointCloud]] = []
        """With :attr:`placed_at_end`: each keyframe's cloud in its camera frame, by id."""

    def add(
        self, kf: KeyFrame, frame: Frame, labels: np.ndarray | None, region: np.ndarray | None
    ) -> None:
        """A new keyframe ``kf`` (its id, its pose now) of ``frame`` (colour, depth), with the
        frame's ``(H, W)`` uint8 class ids (None: not segmented) and the ``(H, W)`` bool dynamic
        ``region`` of the filters (None: none), which is kept out of the products."""
        rgb, depth = frame.rgb, frame.depth
        if self.placed_at_end:
            own = SemanticMapBuilder(self.config, self.extractor)
            own.add(np.eye(4), rgb, depth, labels, region)
            self.keyframe_clouds.append((kf.id, own.build()))
        else:
            self.cloud.add(kf.pose_wc, rgb, depth, labels, region)
        if self.octo is not None:
            self.octo.add(kf.id, rgb, depth, labels, region)

    def build_cloud(self, pose_wc: Callable[[int], np.ndarray]) -> PointCloud:
        """The point cloud, each keyframe at ``pose_wc(id)`` (4, 4) when placed at the end."""
        if not self.placed_at_end:
            return self.cloud.build()
        placed = []
        for kf_id, c in self.keyframe_clouds:
            pose = pose_wc(kf_id)
            points = (c.points @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32)
            placed.append(PointCloud(points, c.colors, c.labels))
        return merge_clouds(placed, self.config.voxel)

    def build_octomap(self, pose_wc: Callable[[int], np.ndarray]) -> SemanticOctoMap | None:
        """The OctoMap, every keyframe at ``pose_wc(id)``; None without ``octomap``."""
        return self.octo.build(pose_wc) if self.octo is not None else None

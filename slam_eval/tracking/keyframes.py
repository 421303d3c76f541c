"""Keyframe rules of ORB-SLAM2's RGB-D tracking: when a tracked frame becomes a keyframe
(``NeedNewKeyFrame``) and which of its keypoints create map points (``CreateNewKeyFrame``; the
same choice of close points gives the last frame's visual-odometry points, ``UpdateLastFrame``).
Unfiltered walkers fool these rules about as much as they fool ORB-SLAM3: a walker's keypoints
become map points on every keyframe, and keyframes are frequent.
"""

from __future__ import annotations

import numpy as np

from ..frontend.orb import Features
from ..map.slam_map import KeyFrame, SlamMap
from .config import TrackerConfig


def need_keyframe(
    cfg: TrackerConfig,
    slam_map: SlamMap,
    reference: KeyFrame,
    frame_index: int,
    last_relocalisation: int | None,
    frames_since_keyframe: int,
    features: Features,
    matched: np.ndarray,
    dynamic: np.ndarray,
) -> bool:
    """ORB-SLAM2's ``NeedNewKeyFrame`` (RGB-D) for frame ``frame_index`` tracked with
    ``matched`` (N,) map point per keypoint against its ``reference`` keyframe: not within
    ``max_keyframe_interval`` frames of a relocalisation (once the map holds more keyframes than
    that); otherwise a keyframe when ``(c1a or c1b or c1c) and c2``: c2 = fewer inliers than
    ``keyframe_ratio`` (0.4 with one keyframe) × the reference keyframe's points seen by two
    keyframes or more (one, while the map holds two keyframes or fewer; ORB-SLAM2 counts an
    RGB-D observation twice), or too few close points tracked (< ``min_close_tracked``) while
    many are not (> ``min_close_untracked``), with more than 15 inliers; c1a =
    ``max_keyframe_interval`` frames since the last keyframe, c1b = ``keyframe_min_frames``
    frames and local mapping idle (always, here), c1c = inliers below a quarter of the
    reference's or the close rule."""
    n_kfs = len(slam_map.keyframes)
    if (
        last_relocalisation is not None
        and frame_index < last_relocalisation + cfg.max_keyframe_interval
        and n_kfs > cfg.max_keyframe_interval
    ):
        return False
    min_obs = 2 if n_kfs > 2 else 1
    ids = reference.point_ids[reference.point_ids >= 0]
    pts = slam_map.points
    ids = ids[~pts.bad.view[ids]]
    ref_tracked = int((pts.observations.view[ids] >= min_obs).sum())
    inliers = int((matched >= 0).sum())
    close = (features.depth > 0) & (features.depth < cfg.th_depth) & ~dynamic
    tracked_close = int((close & (matched >= 0)).sum())
    untracked_close = int((close & (matched < 0)).sum())
    need_close = tracked_close < cfg.min_close_tracked and untracked_close > cfg.min_close_untracked
    ratio = cfg.keyframe_ratio if n_kfs >= 2 else 0.4
    since = frames_since_keyframe + 1
    c1a = since >= cfg.max_keyframe_interval
    c1b = since >= cfg.keyframe_min_frames
    c1c = inliers < 0.25 * ref_tracked or need_close
    c2 = (inliers < ratio * ref_tracked or need_close) and inliers > 15
    return (c1a or c1b or c1c) and c2


def new_points(
    cfg: TrackerConfig, features: Features, tracked: np.ndarray, static: np.ndarray
) -> np.ndarray:
    """ORB-SLAM2's ``CreateNewKeyFrame`` (RGB-D): the static keypoints with depth, nearest
    first, get a map point unless they are tracked, until past ``th_depth`` with
    ``min_new_points`` counted (tracked ones included). Returns the (N,) boolean mask."""
    chosen = nearest_close(cfg, features, np.flatnonzero(static & features.has_depth), 0)
    create = np.zeros(len(features), bool)
    create[chosen[~tracked[chosen]]] = True
    return create


def nearest_close(
    cfg: TrackerConfig, features: Features, candidates: np.ndarray, counted: int
) -> np.ndarray:
    """ORB-SLAM2's choice of points from depth (``CreateNewKeyFrame``, ``UpdateLastFrame``):
    the ``candidates`` nearest first, every one within ``th_depth`` and the nearest ones
    beyond it until ``min_new_points`` are counted (``counted`` already are)."""
    order = candidates[np.argsort(features.depth[candidates], kind="stable")]
    keep = (features.depth[order] <= cfg.th_depth) | (
        np.arange(len(order)) + counted < cfg.min_new_points
    )
    return order[keep]

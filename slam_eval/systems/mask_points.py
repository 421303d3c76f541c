"""What a delivered mask of the semantic thread (``segment=thread``) judges by projecting map
points into its keyframe, beyond the points that keyframe observes itself
(:func:`~.semantic_thread.mark_dynamic_points`):

- :func:`mark_projected` (``slam.mask_marks_projected``): the points mapped since the previous
  mask's keyframe that fall on its people, or in front of them;
- :func:`hold_new_points` / :func:`settle_provisional` (``slam.provisional_points``): a
  keyframe's new points held back until a mask clears or drops them.
"""

from __future__ import annotations

import numpy as np

from ..filters.base import values_at
from ..geometry import invert, project, transform
from ..map.slam_map import SlamMap

PROVISIONAL_DEPTH = 0.05
"""A provisional point agrees with a mask's depth within this share of its depth (at least as
many metres)."""


def hold_new_points(slam_map: SlamMap, kf_id: int, near: np.ndarray | None = None) -> np.ndarray:
    """Make the good map points keyframe ``kf_id`` created provisional (marked bad until a mask
    clears them: :func:`settle_provisional`), with ``near`` ((H, W) bool) only those observed
    through a keypoint inside it; returns their ids."""
    kf = slam_map.keyframes[kf_id]
    ids = kf.point_ids
    if near is not None:
        ids = ids[values_at(near, kf.features.xy)]
    ids = ids[ids >= 0]
    pts = slam_map.points
    ids = ids[(pts.first_keyframe.view[ids] == kf_id) & ~pts.bad.view[ids]]
    pts.bad.view[ids] = True
    return ids


def settle_provisional(
    slam_map: SlamMap,
    ids: np.ndarray,
    kf_id: int,
    region: np.ndarray,
    depth: np.ndarray,
    k: np.ndarray,
) -> tuple[np.ndarray, int, int]:
    """Judge the provisional points ``ids`` by keyframe ``kf_id``'s mask (``region`` (H, W) bool
    dynamic pixels, ``depth`` (H, W) m): each that projects into it (in front, inside the image)
    is cleared (good again) outside the region where the measured depth agrees
    (:data:`PROVISIONAL_DEPTH`), dropped (stays bad) inside the region or where the depth
    disagrees; returns the ids still provisional, and how many were cleared and dropped."""
    if len(ids) == 0:
        return ids, 0, 0
    pts = slam_map.points
    z, inside, uu, vv = _pixels_of(slam_map, kf_id, ids, k, region.shape)
    dyn = region[vv, uu]
    measured = depth[vv, uu]
    agree = (measured > 0) & (
        np.abs(measured - z) <= np.maximum(PROVISIONAL_DEPTH, PROVISIONAL_DEPTH * z)
    )
    clear = inside & ~dyn & agree
    drop = inside & (dyn | ((measured > 0) & ~agree))
    pts.bad.view[ids[clear]] = False
    return ids[~(clear | drop)], int(clear.sum()), int(drop.sum())


def _pixels_of(
    slam_map: SlamMap, kf_id: int, ids: np.ndarray, k: np.ndarray, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Map points ``ids`` in keyframe ``kf_id``'s image of ``shape`` (H, W): their depth ``z``,
    ``inside`` (in front and within the image) and the pixel ``u``, ``v`` each rounds to (0
    where not inside, so that they index safely)."""
    p = transform(invert(slam_map.pose_wc(kf_id)), slam_map.points.position.view[ids])
    z = p[:, 2]
    front = z > 1e-3
    uv = np.rint(project(k, np.where(front[:, None], p, (0.0, 0.0, 1.0)))).astype(np.int64)
    u, v = uv[:, 0], uv[:, 1]
    h, w = shape[:2]
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return z, inside, np.where(inside, u, 0), np.where(inside, v, 0)


def mark_projected(
    slam_map: SlamMap,
    kf_id: int,
    region: np.ndarray,
    depth: np.ndarray,
    k: np.ndarray,
    since: int,
) -> int:
    """Mark bad the good map points first mapped by a keyframe after ``since`` (whose masks never
    judged them) that project, by keyframe ``kf_id``'s map pose, into its mask's dynamic
    ``region`` ((H, W) bool) no farther than the depth measured there (``depth`` (H, W) m, with
    :data:`PROVISIONAL_DEPTH`'s tolerance; no depth there counts as near): on a person now, or in
    front of one. Behind the measured surface a point is the background the person hides, and
    stays. Returns how many points it marked."""
    pts = slam_map.points
    ids = np.flatnonzero(~pts.bad.view & (pts.first_keyframe.view > since))
    if len(ids) == 0:
        return 0
    z, inside, uu, vv = _pixels_of(slam_map, kf_id, ids, k, region.shape)
    measured = depth[vv, uu]
    near = (measured <= 0) | (z <= measured + np.maximum(PROVISIONAL_DEPTH, PROVISIONAL_DEPTH * z))
    hit = ids[inside & region[vv, uu] & near]
    pts.bad.view[hit] = True
    return len(hit)

"""ORB-SLAM2's ``Optimizer::OptimizeEssentialGraph`` on GTSAM: after a loop is verified and its
keyframes corrected rigidly, an SE(3) pose graph over the essential graph (spanning tree, loop
links, strong covisibility) spreads the correction over every keyframe, and each map point
follows its reference keyframe. Loop closing (:mod:`..mapping.loop_closing`) runs it.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..geometry import invert
from ..map.slam_map import KeyFrame, SlamMap
from .local_ba import FIXED_SIGMA, pose_key


def optimise_essential_graph(
    slam_map: SlamMap,
    current: int,
    loop_keyframe: int,
    uncorrected: dict[int, np.ndarray],
    links: dict[int, set[int]],
    reference: np.ndarray,
    loop_edges: list[tuple[int, int]],
    min_covisibility: int,
    iterations: int,
) -> None:
    """SE(3) pose graph over the essential graph (ORB-SLAM2's ``OptimizeEssentialGraph``,
    with unit information per edge), then every map point moved with its reference
    keyframe. ``current`` / ``loop_keyframe``: the keyframes of the loop; ``uncorrected``
    their side's (4, 4) poses before the correction, by id; ``links`` the new loop links;
    ``reference`` (P,) the keyframe that corrected each point (-1: none); ``loop_edges`` the
    earlier loops; edges of at least ``min_covisibility`` shared points; ``iterations`` of LM."""
    kfs = slam_map.keyframes
    good = [k.id for k in kfs if not k.bad]
    before = {k: kfs[k].pose_wc.copy() for k in good}
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    unit = gtsam.noiseModel.Unit.Create(6)
    for k in good:
        values.insert(pose_key(k), gtsam.Pose3(before[k]))
    graph.add(
        gtsam.PriorFactorPose3(
            pose_key(loop_keyframe),
            gtsam.Pose3(before[loop_keyframe]),
            gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA),
        )
    )
    edges: set[tuple[int, int]] = set()

    def add(a: int, b: int, poses: dict[int, np.ndarray]) -> None:
        key = (min(a, b), max(a, b))
        if a == b or key in edges or kfs[a].bad or kfs[b].bad:
            return
        edges.add(key)
        relative = invert(poses[a]) @ poses[b]
        graph.add(gtsam.BetweenFactorPose3(pose_key(a), pose_key(b), gtsam.Pose3(relative), unit))

    # New loop links, measured in the corrected map.
    for g, others in links.items():
        for o in others:
            weight = len(np.intersect1d(_points(kfs[g]), _points(kfs[o])))
            if (g == current and o == loop_keyframe) or weight >= min_covisibility:
                add(g, o, before)
    add(current, loop_keyframe, before)
    # Spanning tree, earlier loops, strong covisibility: measured before the correction.
    for k in good:
        parent = kfs[k].parent
        if parent is not None:
            add(parent, k, uncorrected)
    for a, b in loop_edges:
        add(a, b, uncorrected)
    for k in good:
        for o in slam_map.covisible(k, min_covisibility):
            add(k, int(o), uncorrected)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    for k in good:
        kfs[k].pose_wc = result.atPose3(pose_key(k)).matrix()
    # Points: with the keyframe that corrected them (its pose after the rigid correction is
    # theirs), else with the one that created them (its pose before the correction).
    pts = slam_map.points
    ids = np.flatnonzero(~pts.bad.view)
    side = reference[ids] >= 0
    ref = np.where(side, reference[ids], pts.first_keyframe.view[ids])
    for r, on_side in sorted(set(zip(ref.tolist(), side.tolist(), strict=True))):
        sel = ids[(ref == r) & (side == on_side)]
        old = slam_map.pose_wc(r, before if on_side else uncorrected)
        change = slam_map.pose_wc(r) @ invert(old)
        pts.position.view[sel] = pts.position.view[sel] @ change[:3, :3].T + change[:3, 3]


def _points(kf: KeyFrame) -> np.ndarray:
    return kf.point_ids[kf.point_ids >= 0]

"""Loop closing, as ORB-SLAM2's ``LoopClosing`` thread with a fixed scale (RGB-D): detect that the
camera is back at a place it mapped long ago, verify it geometrically, and spread the correction
over the map with an SE(3) pose graph on GTSAM.

Per new keyframe ``K`` (not within ``min_keyframes`` of the start or of the last loop):

1. **Candidates**: keyframes not covisible with ``K`` (sharing fewer than ``covisibility`` points
   with it), scored by descriptor matches of ``K``'s static keypoints to their map points (nearest
   neighbour in Hamming distance, ratio test, as the tracker's relocalisation; ORB-SLAM2 scores
   with its bag of words), at least ``min_matches``; the ``candidates`` best are kept.
2. **Consistency** (ORB-SLAM2's ``DetectLoop``): a candidate and its covisible keyframes form a
   group; a group that overlaps a group of the previous keyframe's detection inherits its count
   + 1. A candidate is accepted once its count reaches ``consistency`` (ORB-SLAM2: 3), i.e. the
   same place was recognised from ``consistency`` + 1 consecutive keyframes.
3. **Geometric verification** (ORB-SLAM2's ``ComputeSim3``, scale fixed): PnP-RANSAC of ``K``'s
   keypoints on the candidate's matched map points and the RGB-D refinement of the tracker,
   ``min_inliers`` inliers; then the map points of the candidate and its covisible keyframes are
   projected into ``K`` with that pose and matched, and after refining on all of them
   ``min_projected`` inliers are needed (ORB-SLAM2: 20 and 40).
4. **Plausibility** (not ORB-SLAM2's): the correction the verified pose makes to ``K`` must fit
   the motion since the loop keyframe (``correction_ratio`` of the path travelled between them,
   in metres and in degrees, plus a small floor); a correction beyond it is rejected as a wrong
   match before it changes the map.
5. **Correction** (``CorrectLoop``): ``K`` and its covisible keyframes are moved rigidly to the
   verified pose, their map points with them; the loop side's map points are fused into them
   (duplicates replaced, unmatched keypoints given the loop's points). Then the **essential
   graph** is optimised with Levenberg–Marquardt: all keyframes, the loop keyframe fixed, one
   ``BetweenFactorPose3`` per edge of the spanning tree, per pair sharing at least
   ``essential_covisibility`` points (ORB-SLAM2: 100), per earlier loop and per new loop link
   (the relative poses measured before the correction, the new links' after it). Every map point
   then moves with its reference keyframe (the one that corrected it, else the one that created
   it). ``global_ba`` finishes with a bundle adjustment of the whole map (ORB-SLAM2 runs one in a
   thread after each loop), ``global_ba_iterations`` LM iterations.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from uss_slam.core.schema import check_fields, ranged

from ..geometry import invert, rotation_angle_deg
from ..map.slam_map import KeyFrame, SlamMap
from ..matching.keyframe import match_keyframe
from ..matching.projection import ProjectionMatcher
from ..matching.sampling import PoseSampler
from ..optim.essential_graph import optimise_essential_graph
from ..optim.local_ba import BundleAdjuster


@dataclass(frozen=True)
class LoopClosingConfig:
    """Loop detection, verification and correction (defaults: ORB-SLAM2's where it has one)."""

    min_keyframes: int = ranged(10, min=0)
    """No detection before the map has this many keyframes, nor within this many keyframes of
    the last loop (ORB-SLAM2: 10)."""
    covisibility: int = ranged(15, min=0)
    """Keyframes sharing at least this many points with the current one are not candidates."""
    min_matches: int = ranged(30, min=1)
    """Descriptor matches a candidate needs before it is considered."""
    candidates: int = ranged(3, min=1)
    """The best-scoring candidates kept per keyframe."""
    ratio: float = ranged(0.75, gt=0, max=1)
    max_hamming: int = ranged(64, min=0, max=256)
    consistency: int = ranged(3, min=0)
    """Consecutive consistent detections needed (ORB-SLAM2: 3)."""
    min_inliers: int = ranged(20, min=1)
    """PnP inliers of the geometric verification (ORB-SLAM2's Sim3 RANSAC: 20)."""
    min_projected: int = ranged(40, min=1)
    """Inliers after matching the loop's local map by projection (ORB-SLAM2: 40)."""
    search_radius: float = ranged(10.0, min=0)
    """Window of the projection search of the verification, px at level 0 (ORB-SLAM2: 10)."""
    fuse_radius: float = ranged(4.0, min=0)
    """Window of the fusion of the loop's points into the current side, px (ORB-SLAM2: 4)."""
    essential_covisibility: int = ranged(100, min=0)
    """Covisibility edges of the essential graph need this many shared points (ORB-SLAM2: 100)."""
    iterations: int = ranged(20, min=1)
    """LM iterations of the essential-graph optimisation (ORB-SLAM2: 20)."""
    correction_ratio: float = ranged(0.25, min=0, max=1)
    """A verified loop is closed only when its correction of the current keyframe fits the motion
    since the loop keyframe: at most this fraction of the path travelled between them (metres
    along the keyframes' centres, and degrees of rotation between consecutive keyframes), plus
    ``correction_floor_m`` / ``correction_floor_deg``. A tracker drifts by a few percent of its
    path; a larger correction is a wrong match, not drift (after 3.5 s of pure rotation a match
    moving the camera by 0.2 m is not a loop). 0 = off."""
    correction_floor_m: float = ranged(0.02, min=0)
    correction_floor_deg: float = ranged(1.0, min=0)
    global_ba: bool = True
    """Bundle-adjust the whole map after each loop closure."""
    global_ba_iterations: int = ranged(10, min=0, needs="global_ba")

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass
class LoopClosure:
    """One closed loop: keyframe ``keyframe`` (of frame ``frame``) recognised ``loop_keyframe``
    (of frame ``loop_frame``); ``inliers`` of the verification; ``correction_m`` /
    ``correction_deg`` how far the current keyframe moved; ``fused`` points fused."""

    frame: int
    stamp: float
    keyframe: int
    loop_frame: int
    loop_keyframe: int
    inliers: int
    correction_m: float
    correction_deg: float
    fused: int
    wall_ms: float

    def as_dict(self) -> dict[str, float | int]:
        return dict(vars(self))


@dataclass
class _Match:
    """A verified loop: ``pose_cw`` of the current keyframe in the loop's map, and the loop map
    point matched to each of its keypoints (-1 none)."""

    loop_keyframe: int
    pose_cw: np.ndarray
    matched: np.ndarray


class LoopCloser:
    """Detects and closes loops on the keyframes of the shared map (feed :meth:`process` each
    new keyframe after local mapping). A loop is verified as a frame is tracked: with the
    ``projection`` matching and the ``sampler``'s pose estimation that tracking uses (the same
    objects, so that a seeded repeat draws from one random stream)."""

    def __init__(
        self,
        config: LoopClosingConfig,
        slam_map: SlamMap,
        projection: ProjectionMatcher,
        sampler: PoseSampler,
        adjuster: BundleAdjuster,
    ) -> None:
        self.config, self.adjuster = config, adjuster
        self.map, self.projection, self.sampler = slam_map, projection, sampler
        self.closures: list[LoopClosure] = []
        self.loop_edges: list[tuple[int, int]] = []
        self._groups: list[tuple[set[int], int]] = []
        self._last_loop = -1
        self.detection_s = 0.0
        self.rejected = 0
        """Consistent candidates that failed the geometric verification or whose correction
        did not fit the motion since the loop keyframe (:meth:`fits_motion`)."""

    # ------------------------------------------------------------------ detection

    def process(self, keyframe: KeyFrame) -> LoopClosure | None:
        """Look for a loop at ``keyframe`` and close it; returns the closure or None."""
        cfg = self.config
        if keyframe.bad or keyframe.id < cfg.min_keyframes:
            return None
        if self._last_loop >= 0 and keyframe.id < self._last_loop + cfg.min_keyframes:
            return None
        start = time.perf_counter()
        candidates = self._consistent(keyframe, self._candidates(keyframe))
        match = None
        for loop_kf, kp, pid, distance in candidates:
            match = self._verify(keyframe, loop_kf, kp, pid, distance)
            if match is not None and self.fits_motion(keyframe, match.loop_keyframe, match.pose_cw):
                break
            match = None
            self.rejected += 1
        self.detection_s += time.perf_counter() - start
        if match is None:
            return None
        closure = self._correct(keyframe, match)
        closure.wall_ms = 1000.0 * (time.perf_counter() - start)
        self.closures.append(closure)
        self._last_loop = keyframe.id
        self._groups = []
        return closure

    def _candidates(self, kf: KeyFrame) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
        """``(keyframe id, keypoints of kf, matched map points, distances)`` of the best-scoring
        keyframes not covisible with ``kf``."""
        cfg = self.config
        near = set(int(k) for k in self.map.covisible(kf.id, cfg.covisibility)) | {kf.id}
        query = np.flatnonzero(~kf.dynamic)
        if len(query) < cfg.min_matches:
            return []
        scored = []
        for other in self.map.keyframes:
            if other.bad or other.id in near:
                continue
            found = match_keyframe(
                self.map, kf.features, query, other, cfg.ratio, cfg.max_hamming, cfg.min_matches
            )
            if found is not None and len(found[0]) >= cfg.min_matches:
                scored.append((len(found[0]), other.id, *found))
        scored.sort(key=lambda c: (-c[0], c[1]))
        return [c[1:] for c in scored[: cfg.candidates]]

    def _consistent(self, kf: KeyFrame, candidates: list) -> list:
        """ORB-SLAM2's group consistency: the candidates whose group has been seen by
        ``consistency`` consecutive earlier keyframes."""
        cfg = self.config
        groups: list[tuple[set[int], int]] = []
        accepted = []
        for cand in candidates:
            group = set(int(k) for k in self.map.covisible(cand[0], cfg.covisibility))
            group.add(cand[0])
            count = 0
            for previous, n in self._groups:
                if group & previous:
                    count = max(count, n + 1)
            groups.append((group, count))
            if count >= cfg.consistency:
                accepted.append(cand)
        self._groups = groups
        return accepted

    # ------------------------------------------------------------------ verification

    def _verify(
        self, kf: KeyFrame, loop_id: int, kp: np.ndarray, pid: np.ndarray, distance: np.ndarray
    ) -> _Match | None:
        cfg = self.config
        pts = self.map.points
        features = kf.features
        found = self.sampler.pnp_global(pts.position.view[pid], features, kp, distance)
        if found is None or found[1].sum() < cfg.min_inliers:
            return None
        pose_cw = found[0]
        group = np.union1d(self.map.covisible(loop_id, cfg.covisibility), [loop_id])
        loop_points = self.map.points_of(group.astype(np.int64))
        available = ~kf.dynamic
        ids, m = self.projection.match_map_points(
            loop_points, pose_cw, features, available, cfg.search_radius
        )
        if len(m) < cfg.min_projected:
            return None
        pose_cw, inl = self.sampler.refine_pose(
            pts.position.view[ids[m.query]], features, m.keypoint, pose_cw
        )
        if inl.sum() < cfg.min_projected:
            return None
        matched = np.full(len(features), -1, np.int64)
        matched[m.keypoint[inl]] = ids[m.query[inl]]
        return _Match(loop_id, pose_cw, matched)

    def fits_motion(self, kf: KeyFrame, loop_id: int, pose_cw: np.ndarray) -> bool:
        """Does moving ``kf`` to ``pose_cw`` (the verified pose) fit the motion since keyframe
        ``loop_id`` (``correction_ratio``)? The path runs over every keyframe between the two,
        culled ones at the pose they follow."""
        cfg = self.config
        if cfg.correction_ratio == 0:
            return True
        lo, hi = sorted((int(loop_id), int(kf.id)))
        poses = [self.map.pose_wc(k) for k in range(lo, hi + 1)]
        steps = list(zip(poses[:-1], poses[1:], strict=True))
        path_m = sum(float(np.linalg.norm(b[:3, 3] - a[:3, 3])) for a, b in steps)
        path_deg = sum(rotation_angle_deg(a[:3, :3].T @ b[:3, :3]) for a, b in steps)
        corrected = invert(pose_cw)
        shift_m = float(np.linalg.norm(corrected[:3, 3] - kf.center))
        shift_deg = rotation_angle_deg(kf.pose_wc[:3, :3].T @ corrected[:3, :3])
        return bool(
            shift_m <= cfg.correction_ratio * path_m + cfg.correction_floor_m
            and shift_deg <= cfg.correction_ratio * path_deg + cfg.correction_floor_deg
        )

    # ------------------------------------------------------------------ correction

    def _correct(self, kf: KeyFrame, match: _Match) -> LoopClosure:
        cfg = self.config
        slam_map = self.map
        pts = slam_map.points
        kfs = slam_map.keyframes
        uncorrected = {k.id: k.pose_wc.copy() for k in kfs if not k.bad}
        group = [kf.id] + [int(k) for k in slam_map.covisible(kf.id, cfg.covisibility)]
        neighbours_before = {g: set(int(k) for k in slam_map.covisible(g, 1)) for g in group}
        corrected_wc = invert(match.pose_cw)
        moved = corrected_wc @ kf.pose_cw  # world correction of the current side
        old_position = kfs[kf.id].center.copy()
        old_rotation = kfs[kf.id].pose_wc[:3, :3].copy()
        # Move the current side rigidly, and its points with the keyframe that first holds them.
        reference = np.full(slam_map.n_points, -1, np.int64)
        for g in group:
            ids = kfs[g].point_ids
            ids = np.unique(ids[ids >= 0])
            ids = ids[(reference[ids] < 0) & ~pts.bad.view[ids]]
            reference[ids] = g
        side = np.flatnonzero(reference >= 0)
        pts.position.view[side] = pts.position.view[side] @ moved[:3, :3].T + moved[:3, 3]
        for g in group:
            kfs[g].pose_wc = moved @ kfs[g].pose_wc
        # Fuse the loop's points into the current side.
        fused = self._fuse_matched(kf.id, match.matched)
        loop_group = np.union1d(
            slam_map.covisible(match.loop_keyframe, cfg.covisibility), [match.loop_keyframe]
        ).astype(np.int64)
        loop_points = slam_map.points_of(loop_group)
        for g in group:
            fused += self._fuse_projected(kfs[g], loop_points)
        links = {}
        for g in group:
            now = set(int(k) for k in slam_map.covisible(g, 1))
            links[g] = now - neighbours_before[g] - set(group)
        optimise_essential_graph(
            self.map, kf.id, match.loop_keyframe, uncorrected, links, reference,
            self.loop_edges, cfg.essential_covisibility, cfg.iterations,
        )  # fmt: skip
        self.loop_edges.append((match.loop_keyframe, kf.id))
        if cfg.global_ba:
            good = np.array([k.id for k in kfs if not k.bad], np.int64)
            all_points = slam_map.points_of(good)
            self.adjuster.adjust(slam_map, good, all_points, cfg.global_ba_iterations, 0)
        slam_map.update_geometry(slam_map.points_of(np.array([k.id for k in kfs if not k.bad])))
        return LoopClosure(
            frame=kf.frame_index,
            stamp=kf.stamp,
            keyframe=kf.id,
            loop_frame=kfs[match.loop_keyframe].frame_index,
            loop_keyframe=match.loop_keyframe,
            inliers=int((match.matched >= 0).sum()),
            correction_m=float(np.linalg.norm(kf.center - old_position)),
            correction_deg=rotation_angle_deg(old_rotation.T @ kf.pose_wc[:3, :3]),
            fused=fused,
            wall_ms=0.0,
        )

    def _fuse_matched(self, keyframe_id: int, matched: np.ndarray) -> int:
        """Keypoint ``i`` of the keyframe sees loop point ``matched[i]``: replace its own point
        by the loop's, or give it the loop's. Returns how many keypoints changed."""
        slam_map = self.map
        kf = slam_map.keyframes[keyframe_id]
        count = 0
        for i in np.flatnonzero(matched >= 0):
            loop_point = int(matched[i])
            if slam_map.points.bad.view[loop_point]:
                continue
            own = int(kf.point_ids[i])
            if own == loop_point:
                continue
            if own >= 0:
                slam_map.replace_point(own, loop_point)
            elif loop_point not in kf.point_ids:
                slam_map.add_observation(loop_point, keyframe_id, int(i))
            else:
                continue
            count += 1
        return count

    def _fuse_projected(self, kf: KeyFrame, loop_points: np.ndarray) -> int:
        """ORB-SLAM2's ``SearchAndFuse``: the loop's points projected into a current-side
        keyframe (corrected pose) and fused where they match."""
        if kf.bad or len(loop_points) == 0:
            return 0
        loop_points = loop_points[~self.map.points.bad.view[loop_points]]
        ids, m = self.projection.match_map_points(
            loop_points, kf.pose_cw, kf.features, ~kf.dynamic, self.config.fuse_radius
        )
        matched = np.full(len(kf.features), -1, np.int64)
        matched[m.keypoint] = ids[m.query]
        return self._fuse_matched(kf.id, matched)


__all__ = ["LoopCloser", "LoopClosingConfig", "LoopClosure"]

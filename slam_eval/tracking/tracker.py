"""RGB-D tracking in the style of ORB-SLAM2's tracking thread: the tracking loop (the back end,
local bundle adjustment and loop closing, is :mod:`..mapping.local_mapping` and
:mod:`..mapping.loop_closing`; the shared map is :mod:`..map.slam_map`).

Per frame, as ORB-SLAM2's RGB-D ``Tracking``:

1. **Motion model** (``TrackWithMotionModel``): constant velocity, ``T_cw(t) = V · T_cw(t-1)``
   with ``V`` the last inter-frame motion. The last frame's map points and its visual-odometry
   points (its unmatched close keypoints back-projected with its depth, when it is not a
   keyframe) are projected with the prediction and matched in a window of ``search_radius`` ×
   the level's scale (doubled once when too few matches are found). ``motion_ransac`` (on by
   default, not ORB-SLAM2's) seeds the pose optimisation with PnP-RANSAC on those matches
   (:mod:`..matching.sampling`); the pose is then optimised with the robust χ² rounds of
   ``PoseOptimization``. Without a motion model (the second frame, the first after a
   relocalisation) the frame is matched to its reference keyframe by descriptor, as
   ORB-SLAM2's ``TrackReferenceKeyFrame`` (``reference_keyframe``); failing that, the frame is
   lost and relocalised, never tracked with a zero-motion guess (``reference_keyframe=false``
   projects the local map with the last pose instead, and PnP-RANSAC or PROSAC,
   ``sampler="prosac"``, estimates the pose).
2. **Local-map tracking** (``TrackLocalMap``): the points of the keyframes that share the most
   points with the previous frame, plus the latest keyframe, are projected with the estimated
   pose, matched in a tight window (``local_radius``; ``reloc_local_radius`` on the frame that
   relocalises and the next, as ORB-SLAM2's ``SearchLocalPoints``, :meth:`Tracker.local_window`),
   and the pose refined on all matches. Tracking succeeds with ``min_inliers``
   (``reloc_min_inliers`` during the ``reloc_recent_frames`` frames after a relocalisation, as
   ORB-SLAM2). A pose that fails a later inlier check (too few inliers left once the post-pose
   filters drop keypoints) is taken back: lost (:meth:`Tracker.mark_lost`), never in the map.
3. **Keyframes** follow ``NeedNewKeyFrame`` and create map points from their close keypoints
   as ``CreateNewKeyFrame`` (:mod:`.keyframes`); recent points that are rarely found are culled.
4. **Relocalisation** when lost (:mod:`.relocalisation`): descriptor matches, PnP, local map.

Keypoints flagged dynamic are never matched and never create map points. Unfiltered walkers
fool this tracking about as much as they fool ORB-SLAM3.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from functools import partial

import numpy as np

from ..frontend.orb import Features, OrbExtractor
from ..geometry import invert, transform
from ..map.slam_map import KeyFrame, SlamMap
from ..matching import settings_of
from ..matching.keyframe import match_keyframe
from ..matching.projection import MatchThresholds, ProjectionMatcher
from ..matching.sampling import PoseSampler, SamplingSettings
from .config import SAMPLERS, TrackerConfig
from .keyframes import nearest_close, need_keyframe, new_points
from .relocalisation import relocalise
from .rolling_shutter import readout_of, twist, unroll


class TrackingState(str, Enum):
    NOT_INITIALIZED = "not_initialized"
    OK = "ok"
    LOST = "lost"


@dataclass
class TrackResult:
    """Outcome of one frame.

    ``pose_wc`` (4, 4) camera-to-world or None when not tracked; ``matched`` (N,) map point id per
    keypoint (-1 = none) after outlier rejection; ``inliers`` the number of such matches.
    """

    state: TrackingState
    pose_wc: np.ndarray | None
    matched: np.ndarray
    inliers: int
    relocalised: bool = False
    new_keyframe: KeyFrame | None = None


class Tracker:
    """Frame-to-local-map RGB-D tracker. Feed frames in order with :meth:`track`."""

    def __init__(
        self, config: TrackerConfig, extractor: OrbExtractor, sampling_seed: int | None = None,
        slam_map: SlamMap | None = None,
    ) -> None:  # fmt: skip
        """``sampling_seed``: None = RANSAC samples as OpenCV does (deterministic); an integer
        perturbs the sampling reproducibly, for repeats (:meth:`.PoseSampler.sampling_order`).
        ``slam_map``: the map shared with the back end and the filters (None: one of its own)."""
        self.config = config
        rng = None if sampling_seed is None else np.random.default_rng(sampling_seed)
        self.extractor = extractor
        self.camera = extractor.camera
        self.k = extractor.camera.matrix
        self.size = (extractor.camera.width, extractor.camera.height)
        self.sigma2 = extractor.sigma2
        self.bf = extractor.camera.fx * config.virtual_baseline
        sampling = settings_of(SamplingSettings, config)
        self.sampler = PoseSampler(sampling, self.k, self.sigma2, self.bf, rng)
        self.map = slam_map or SlamMap(extractor.config.scale_factor, extractor.config.n_levels)
        matching = settings_of(MatchThresholds, config)
        self.projection = ProjectionMatcher(matching, self.map, self.k, self.size, extractor.scales)
        self.state = TrackingState.NOT_INITIALIZED
        self.velocity: np.ndarray | None = None
        self.velocity_dt = 0.0
        """Seconds between the two frames :attr:`velocity` was measured on."""
        self.last_stamp: float | None = None
        self.readout, self.readout_from = readout_of(config.readout, self.camera.readout)
        self.last_pose_cw: np.ndarray | None = None
        self.last_points = np.zeros(0, np.int64)
        self.reference: KeyFrame | None = None
        self._last_in_reference: np.ndarray | None = None
        self.frames_since_keyframe = 0
        self._previous_tracked = False
        self.relocalisations = 0
        self.last_relocalisation: int | None = None
        """Frame of the last relocalisation (or first keyframe: ``start_as_relocalisation``)."""
        self.lost_events = 0
        self._current_index = 0
        self._last_frame_keypoints = np.zeros(0, np.int64)
        """Keypoints of the last frame behind :meth:`_last_frame_points`' points, in order."""
        self._last_frame: tuple[Features, np.ndarray, np.ndarray] | None = None
        """The last tracked frame's features, its map point per keypoint
        and the keypoints its visual odometry may use (static, not a keyframe's)."""

    # ------------------------------------------------------------------ public

    def track(
        self, frame_index: int, stamp: float, features: Features, dynamic: np.ndarray
    ) -> TrackResult:
        """Estimate the pose of a frame; ``dynamic`` (N,) bool marks keypoints to ignore."""
        self._current_index = frame_index
        n = len(features)
        matched = np.full(n, -1, np.int64)
        static = ~dynamic
        if self.state is TrackingState.NOT_INITIALIZED:
            close = static & features.has_depth
            if int(close.sum()) < self.config.init_min_points:
                return TrackResult(self.state, None, matched, 0)
            pose_wc = np.eye(4)
            kf = self.map.add_keyframe(
                frame_index, stamp, pose_wc, features, matched, dynamic, close
            )
            self._accept(invert(pose_wc), stamp, kf.point_ids[close], kf)
            self._last_frame = (features, kf.point_ids, np.zeros(n, bool))
            self.state = TrackingState.OK
            self.last_relocalisation = frame_index if self.config.start_as_relocalisation else None
            return TrackResult(
                self.state, pose_wc, kf.point_ids.copy(), int(close.sum()), False, kf
            )

        relocalised = False
        pose_cw = None
        if self.state is TrackingState.OK:
            pose_cw, matched = self._track_motion(features, static)
            # ORB-SLAM2 is more restrictive right after a relocalisation.
            if (
                pose_cw is not None
                and self._recently_relocalised(frame_index, self.config.reloc_recent_frames)
                and int((matched >= 0).sum()) < self.config.reloc_min_inliers
            ):
                pose_cw = None
        if pose_cw is None:
            if self.state is TrackingState.OK:
                self.lost_events += 1
            self.state = TrackingState.LOST
            # ORB-SLAM2 sets mnLastRelocFrameId before this frame's TrackLocalMap: the wider
            # window already holds for the frame that relocalises.
            radius = self.local_window(frame_index, relocalising=True)
            track_local_map = partial(self._track_local_map, radius=radius)
            pose_cw, matched = relocalise(
                self.config, self.map, self.sampler, track_local_map, features, static
            )
            relocalised = pose_cw is not None
            if relocalised:
                self.relocalisations += 1
                self.last_relocalisation = frame_index
                self.velocity = None
        if pose_cw is None:
            self._previous_tracked = False
            return TrackResult(self.state, None, np.full(n, -1, np.int64), 0)
        self.state = TrackingState.OK
        inliers = int((matched >= 0).sum())
        return TrackResult(self.state, invert(pose_cw), matched, inliers, relocalised)

    def unroll(self, features: Features) -> Features:
        """The frame's keypoints corrected for the rolling shutter (:mod:`.rolling_shutter`)
        with the motion model's velocity, for tracking (first pass; :meth:`unroll_tracked` is the
        second); unchanged without a readout or a motion model."""
        if (
            self.readout == 0
            or self.state is not TrackingState.OK
            or self.velocity is None
            or not self.velocity_dt > 0
        ):
            return features
        omega, linear = twist(self.velocity, self.velocity_dt)
        return unroll(features, omega, linear, self.readout, self.k, self.size[1])

    def unroll_tracked(
        self, raw: Features, features: Features, stamp: float, result: TrackResult
    ) -> Features:
        """Second rolling-shutter pass once the frame is tracked: correct the ``raw`` keypoints
        with the camera's velocity over the last frame interval (this frame's pose against the
        previous one's) and refine the pose on the same matches; ``result`` is updated in place.
        Returns the keypoints the rest of the frame uses: ``features`` (the first pass's) when
        there is no previous tracked frame, the frame made a keyframe or relocalised, or the
        refinement would keep fewer than ``min_inliers`` matches."""
        if (
            self.readout == 0
            or result.pose_wc is None
            or result.new_keyframe is not None
            or result.relocalised
            or not self._previous_tracked
            or self.last_pose_cw is None
            or self.last_stamp is None
            or not stamp > self.last_stamp
        ):
            return features
        pose_cw = invert(result.pose_wc)
        omega, linear = twist(pose_cw @ invert(self.last_pose_cw), stamp - self.last_stamp)
        again = unroll(raw, omega, linear, self.readout, self.k, self.size[1])
        keep = result.matched >= 0
        if keep.sum() < self.config.min_inliers:
            return features
        refined, matched = self._refine_matches(pose_cw, again, result.matched, keep)
        inliers = int((matched >= 0).sum())
        if inliers < self.config.min_inliers:
            return features
        result.pose_wc, result.matched, result.inliers = invert(refined), matched, inliers
        return again

    def refine_without(
        self, pose_wc: np.ndarray, features: Features, matched: np.ndarray, drop: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray]:
        """Re-estimate a tracked pose without the keypoints the post-pose filters flagged.

        ``drop`` (N,) bool. Returns ``(pose_wc, matched)`` with the dropped keypoints unmatched;
        ``(None, all -1)`` when fewer than ``min_inliers`` inliers would remain: the pose leant
        on the dropped keypoints and fails the inlier check (the caller marks the frame lost,
        :meth:`mark_lost`).
        """
        keep = (matched >= 0) & ~drop
        if not np.any(drop & (matched >= 0)):
            return pose_wc, np.where(drop, -1, matched)
        if keep.sum() < self.config.min_inliers:
            return None, np.full(len(matched), -1, np.int64)
        pose_cw, out = self._refine_matches(invert(pose_wc), features, matched, keep)
        if int((out >= 0).sum()) < self.config.min_inliers:
            return None, np.full(len(matched), -1, np.int64)
        return invert(pose_cw), out

    def mark_lost(self, result: TrackResult) -> None:
        """Take back a tracked frame whose pose failed a later check (too few inliers after the
        post-pose filters, a frame without depth): it gets no pose, adds nothing to the map and
        the next frame relocalises, as a frame lost in :meth:`track`. ``result`` is updated in
        place."""
        if self.state is TrackingState.OK:
            self.lost_events += 1
        if self.state is not TrackingState.NOT_INITIALIZED:
            self.state = TrackingState.LOST
        self._previous_tracked = False
        self.velocity = None
        result.state = self.state
        result.pose_wc = None
        result.matched = np.full(len(result.matched), -1, np.int64)
        result.inliers = 0

    def _refine_matches(
        self, pose_cw: np.ndarray, features: Features, matched: np.ndarray, keep: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`refine_pose` on the matches ``keep`` (N,) bool selects: ``(pose_cw, matched)``
        with only the inliers of the refinement matched."""
        kp = np.flatnonzero(keep)
        pose_cw, inl = self.sampler.refine_pose(
            self.map.points.position.view[matched[kp]], features, kp, pose_cw
        )
        out = np.full(len(matched), -1, np.int64)
        out[kp[inl]] = matched[kp[inl]]
        return pose_cw, out

    def finish_frame(
        self,
        frame_index: int,
        stamp: float,
        result: TrackResult,
        features: Features,
        dynamic: np.ndarray,
        keyframe: bool | None = None,
    ) -> KeyFrame | None:
        """Update motion model, map statistics and keyframes after the filters are done.

        ``keyframe``: None = decide with :meth:`wants_keyframe`; True / False = a decision the
        caller already took (the pipeline asks first when it segments keyframes only, so that
        the new keyframe's map points are created after its semantic filtering).
        """
        if result.pose_wc is None or result.new_keyframe is not None:
            return result.new_keyframe
        pose_cw = invert(result.pose_wc)
        matched = result.matched
        pts = self.map.points
        good = matched >= 0
        pts.found.view[matched[good]] += 1
        kf = None
        if keyframe is None:
            keyframe = self.wants_keyframe(result, features, dynamic)
        if keyframe:
            create = new_points(self.config, features, good, ~dynamic)
            kf = self.map.add_keyframe(
                frame_index, stamp, result.pose_wc, features, matched, dynamic, create
            )
            kf.inliers = int(good.sum())
            self.map.cull(self.config.min_found_ratio, self.config.min_observations)
            self.frames_since_keyframe = 0
            result.new_keyframe = kf
            matched = kf.point_ids
        else:
            self.frames_since_keyframe += 1
        self._accept(pose_cw, stamp, matched[matched >= 0], kf)
        usable = np.zeros(len(features), bool) if kf is not None else ~dynamic
        self._last_frame = (features, matched, usable)
        return kf

    def local_window(self, frame_index: int, relocalising: bool = False) -> float:
        """Window of the local-map search for frame ``frame_index``, px at level 0:
        ``reloc_local_radius`` on the frame that relocalises (``relocalising``) and the frames
        after it, ``reloc_local_frames`` in all, ``local_radius`` otherwise (ORB-SLAM2's
        ``SearchLocalPoints``: th 5 while ``mnId < mnLastRelocFrameId + 2``, else th 3)."""
        cfg = self.config
        if self._recently_relocalised(frame_index, cfg.reloc_local_frames, relocalising):
            return cfg.reloc_local_radius
        return cfg.local_radius

    def _recently_relocalised(
        self, frame_index: int, frames: int, relocalising: bool = False
    ) -> bool:
        """Is ``frame_index`` one of the ``frames`` frames from the last relocalisation on
        (``relocalising``: from this frame, which relocalises now)?"""
        last = frame_index if relocalising else self.last_relocalisation
        return last is not None and frame_index < last + frames

    @property
    def initialized(self) -> bool:
        """The first keyframe exists (before that, every frame is a first-keyframe candidate)."""
        return self.state is not TrackingState.NOT_INITIALIZED

    def wants_keyframe(self, result: TrackResult, features: Features, dynamic: np.ndarray) -> bool:
        """Would :meth:`finish_frame` insert this tracked frame as a keyframe
        (:func:`.keyframes.need_keyframe`; always without a reference keyframe)? False for
        untracked frames and for the first keyframe, already inserted."""
        if result.pose_wc is None or result.new_keyframe is not None:
            return False
        if self.reference is None:
            return True
        return need_keyframe(
            self.config,
            self.map,
            self.reference,
            self._current_index,
            self.last_relocalisation,
            self.frames_since_keyframe,
            features,
            result.matched,
            dynamic,
        )

    # ------------------------------------------------------------------ tracking

    def _accept(
        self, pose_cw: np.ndarray, stamp: float, point_ids: np.ndarray, kf: KeyFrame | None
    ) -> None:
        # The motion model needs two consecutive tracked frames.
        if self._previous_tracked and self.last_pose_cw is not None:
            self.velocity = pose_cw @ invert(self.last_pose_cw)
            assert self.last_stamp is not None
            self.velocity_dt = stamp - self.last_stamp
        else:
            self.velocity = None
        self._previous_tracked = True
        self.last_pose_cw = pose_cw
        self.last_stamp = stamp
        self.last_points = point_ids
        counts = self.map.covisibility(point_ids)
        if kf is not None:
            self.reference = kf
        elif len(counts) and counts.max() > 0:
            self.reference = self.map.keyframes[int(np.argmax(counts))]
        if self.reference is not None:
            self._last_in_reference = pose_cw @ self.reference.pose_wc

    def anchor(self) -> tuple[int, np.ndarray] | None:
        """The last tracked frame relative to its reference keyframe: ``(keyframe id, T_c,kf)``
        (4, 4), what ORB-SLAM2 stores per frame so that its trajectory follows the keyframes
        when the back end moves them; None before the first keyframe."""
        if self.reference is None or self._last_in_reference is None:
            return None
        return self.reference.id, self._last_in_reference.copy()

    def map_changed(self) -> None:
        """The back end moved keyframes: put the last pose back on its reference keyframe
        (ORB-SLAM2's ``UpdateLastFrame``), so that the next prediction is in the corrected map."""
        anchor = self.anchor()
        if anchor is None or self.last_pose_cw is None:
            return
        kf_id, in_reference = anchor
        self.last_pose_cw = in_reference @ invert(self.map.pose_wc(kf_id))
        self._last_in_reference = in_reference

    def _local_points(self) -> np.ndarray:
        counts = self.map.covisibility(self.last_points)
        best = np.argsort(-counts, kind="stable")[: self.config.local_keyframes]
        best = best[counts[best] > 0]
        ids = np.union1d(best, [len(self.map.keyframes) - 1]).astype(np.int64)
        if self.reference is not None:
            ids = np.union1d(ids, [self.reference.id])
        return self.map.points_of(ids)

    def _track_motion(self, features: Features, static: np.ndarray):
        cfg = self.config
        if self.velocity is not None:
            return self._track_last_frame(features, static)
        if cfg.reference_keyframe:
            # No motion model: the reference keyframe or nothing (then relocalisation), never a
            # zero-motion guess, which a camera already turning fast breaks (ORB-SLAM2).
            if self.reference is None:
                return None, None
            return self._track_reference(features, static)
        predicted = self.last_pose_cw
        local = self._local_points()
        ids, m = self.projection.match_map_points(
            local, predicted, features, static, cfg.search_radius
        )
        if len(m) < cfg.min_matches:
            ids, m = self.projection.match_map_points(
                local, predicted, features, static, 2 * cfg.search_radius
            )
        if len(m) < cfg.min_matches:
            return None, None
        pose_cw = self.sampler.pnp(
            self.map.points.position.view[ids[m.query]],
            features,
            m.keypoint,
            predicted,
            m.distance,
        )
        if pose_cw is None:
            return None, None
        return self._track_local_map(local, pose_cw, features, static)

    def _track_last_frame(self, features: Features, static: np.ndarray):
        """ORB-SLAM2's ``TrackWithMotionModel`` + ``TrackLocalMap``.

        The last frame's map points and its visual-odometry points (``UpdateLastFrame``: its
        unmatched close keypoints back-projected with its pose, when it is not a keyframe) are
        projected with the constant-velocity prediction and matched in a window of
        ``search_radius`` (twice that below ``min_matches``; fewer: the reference keyframe is
        tried, then relocalisation); the pose is optimised from the prediction with every match
        an inlier at first (:meth:`.PoseSampler.optimise_all`), ≥ 10 map-point inliers needed; the local map
        then adds its matches and the pose is optimised again on all of them. The visual-odometry
        points steer the pose but are never map points: a walker's keypoints of the last frame
        are such points, re-created on every frame, which is how walkers fool ORB-SLAM2."""
        cfg = self.config
        assert self.velocity is not None and self.last_pose_cw is not None
        predicted = self.velocity @ self.last_pose_cw
        world, desc, level, map_ids = self._last_frame_points()
        angle = self._last_frame_angles()
        for radius in (cfg.search_radius, 2 * cfg.search_radius):
            query, kp = self.projection.match_points(
                world, desc, level, predicted, features, static, radius, angle
            )
            if len(query) >= cfg.min_matches:
                break
        else:
            return self._track_reference_or_lost(features, static)
        if cfg.motion_ransac:
            ransac = self.sampler.pnp(world[query], features, kp, predicted, np.zeros(len(kp)))
            if ransac is None:
                return self._track_reference_or_lost(features, static)
            predicted = ransac
        pose_cw, inl = self.sampler.optimise_all(world[query], features, kp, predicted)
        if int((inl & (map_ids[query] >= 0)).sum()) < 10:
            return self._track_reference_or_lost(features, static)
        query, kp = query[inl], kp[inl]
        return self._track_local_map_vo(pose_cw, features, static, world[query], map_ids[query], kp)

    def _track_reference_or_lost(self, features: Features, static: np.ndarray):
        if self.config.reference_keyframe and self.reference is not None:
            return self._track_reference(features, static)
        return None, None

    def _last_frame_angles(self) -> np.ndarray:
        """``(M,)`` keypoint angles, degrees, of :meth:`_last_frame_points`' points, in order."""
        assert self._last_frame is not None
        feats = self._last_frame[0]
        return feats.angle[self._last_frame_keypoints]

    def _last_frame_points(self):
        """``(world (M, 3), descriptors (M, 32), level (M,), map id or -1 (M,))`` of the last
        frame: its good map points, then its visual-odometry points (nearest first, every one
        closer than ``th_depth`` and ``min_new_points`` at least)."""
        assert self._last_frame is not None and self.last_pose_cw is not None
        feats, ids, usable = self._last_frame
        pts = self.map.points
        has = ids >= 0
        has[has] = ~pts.bad.view[ids[has]]
        own = np.flatnonzero(has)
        # ORB-SLAM2 counts the frame's existing points towards the minimum too.
        candidates = np.flatnonzero(usable & ~has & feats.has_depth)
        vo = nearest_close(self.config, feats, candidates, len(own))
        pose_wc = invert(self.last_pose_cw)
        world = np.concatenate(
            [pts.position.view[ids[own]], transform(pose_wc, feats.points[vo])], axis=0
        )
        desc = np.concatenate([pts.descriptor.view[ids[own]], feats.descriptors[vo]], axis=0)
        level = np.concatenate([feats.octave[own], feats.octave[vo]])
        map_ids = np.concatenate([ids[own], np.full(len(vo), -1, np.int64)])
        self._last_frame_keypoints = np.concatenate([own, vo])
        return world, desc, level, map_ids

    def _track_local_map_vo(self, pose_cw, features, static, world, map_ids, kp):
        """``TrackLocalMap`` with the motion model's matches (map and visual-odometry points)
        kept: the local map's points not matched yet are projected and matched to the free
        keypoints, and the pose is optimised on all matches; ``min_inliers`` map-point inliers
        needed. Returns ``(pose_cw, matched map id per keypoint)``."""
        cfg = self.config
        mine = np.unique(map_ids[map_ids >= 0])
        self.map.points.visible.view[mine] += 1  # SearchLocalPoints counts them as visible
        local = np.setdiff1d(self._local_points(), mine)
        free = static.copy()
        free[kp] = False
        ids, m = self.projection.match_map_points(
            local, pose_cw, features, free, self.local_window(self._current_index), local=True
        )
        world = np.concatenate([world, self.map.points.position.view[ids[m.query]]], axis=0)
        map_ids = np.concatenate([map_ids, ids[m.query]])
        kp = np.concatenate([kp, m.keypoint])
        pose_cw, inl = self.sampler.optimise_all(world, features, kp, pose_cw)
        good = inl & (map_ids >= 0)
        if good.sum() < cfg.min_inliers:
            return None, None
        matched = np.full(len(features), -1, np.int64)
        matched[kp[good]] = map_ids[good]
        return pose_cw, matched

    def _track_reference(self, features: Features, static: np.ndarray):
        """ORB-SLAM2's ``TrackReferenceKeyFrame``, for a frame without a motion model (the
        second frame, the first after a relocalisation): the static keypoints matched to the
        reference keyframe's map points by descriptor (ratio 0.7, no projection window), at
        least 15 matches, PnP-RANSAC seeded with the last pose, then local-map tracking.
        Projecting with the last pose instead misses the matches of a camera that already
        moves fast when tracking starts (a hand-held Kinect turning at 1.5 rad/s moves the
        image ~25 px per frame, beyond twice the 7 px window)."""
        assert self.reference is not None
        found = match_keyframe(
            self.map,
            features,
            np.flatnonzero(static),
            self.reference,
            0.7,
            self.config.max_hamming,
            15,
            self.config.check_orientation,
        )
        if found is None or len(found[0]) < 15:
            return None, None
        kp, pid, distance = found
        pose_cw = self.sampler.pnp(
            self.map.points.position.view[pid], features, kp, self.last_pose_cw, distance
        )
        if pose_cw is None:
            return None, None
        return self._track_local_map(self._local_points(), pose_cw, features, static)

    def _track_local_map(
        self,
        local: np.ndarray,
        pose_cw: np.ndarray,
        features: Features,
        static: np.ndarray,
        radius: float | None = None,
    ):
        """ORB-SLAM2's ``SearchLocalPoints`` + pose optimisation: the ``local`` map points
        matched in ``radius`` px (None = :meth:`local_window` of the current frame)."""
        if radius is None:
            radius = self.local_window(self._current_index)
        ids, m = self.projection.match_map_points(
            local, pose_cw, features, static, radius, local=True
        )
        if len(m) < self.config.min_inliers:
            return None, None
        pose_cw, inl = self.sampler.refine_pose(
            self.map.points.position.view[ids[m.query]], features, m.keypoint, pose_cw
        )
        if inl.sum() < self.config.min_inliers:
            return None, None
        matched = np.full(len(features), -1, np.int64)
        matched[m.keypoint[inl]] = ids[m.query[inl]]
        return pose_cw, matched


__all__ = ["SAMPLERS", "TrackResult", "Tracker", "TrackerConfig", "TrackingState"]

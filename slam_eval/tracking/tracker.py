"""RGB-D tracking in the style of ORB-SLAM2's tracking thread (the back end, local bundle
adjustment and loop closing, is :mod:`..mapping.local_mapping` and :mod:`..mapping.loop_closing`).

Two policies (``TrackerConfig.policy``):

- ``orbslam2`` (the default): ORB-SLAM2's RGB-D ``Tracking``. The motion model matches the last
  frame's map points and visual-odometry points, and the pose is optimised with the robust χ²
  rounds of ``PoseOptimization``. Keyframes follow ``NeedNewKeyFrame`` and map points come from
  a keyframe's close keypoints (``CreateNewKeyFrame``). ``motion_ransac`` (on by default, not
  ORB-SLAM2's) seeds that optimisation with PnP-RANSAC on the motion model's matches; without
  it the policy diverges on synthetic static scenes and on the real ``freiburg1_rpy`` frames.
  Unfiltered walkers fool it about as much as they fool ORB-SLAM3.
- ``harness``: the steps below. Its keyframes are sparser, so walkers fool it far less
  (``slam.tracker.policy=harness slam.tracker.motion_ransac=false``).

Per frame (``harness``; ``orbslam2`` shares steps 1, 4 and 6):

1. **Prediction**: constant velocity, ``T_cw(t) = V · T_cw(t-1)`` with ``V`` the last inter-frame
   motion. Without one (the second frame, the first after a relocalisation) the frame is first
   matched to its reference keyframe by descriptor, as ORB-SLAM2's ``TrackReferenceKeyFrame``
   (``reference_keyframe``), then goes on with step 4.
2. **Guided matching** of the local map (points of the keyframes that share the most points with
   the previous frame, plus the latest keyframe) projected with the predicted pose, in a window of
   ``search_radius`` × the predicted level's scale (doubled once when too few matches are found).
3. **PnP-RANSAC** (``cv2.solvePnPRansac``, seeded with the prediction; or PROSAC, OpenCV's USAC
   sampling the matches in order of descriptor distance, with ``sampler="prosac"``), then
   **refinement**
   (``cv2.solvePnPRefineLM``) alternated with re-classifying inliers by the χ² test of
   ORB-SLAM2 (5.991 × the level's variance).
4. **Local-map tracking**: the local map is projected again with the estimated pose, matched in a
   tight window, and the pose refined on all inliers. Tracking succeeds with ``min_inliers``
   (``reloc_min_inliers`` during the ``reloc_recent_frames`` frames after a relocalisation, as
   ORB-SLAM2).
5. **Keyframes** are inserted when tracking weakens (inliers below ``keyframe_ratio`` × the
   reference keyframe's well-observed points), when few close points are tracked while many
   close points are unmatched (ORB-SLAM2's RGB-D rule), after ``max_keyframe_interval`` frames, or
   when the view moved by ``keyframe_translation`` / ``keyframe_rotation_deg`` from the
   reference keyframe. New keyframes create map points from their unmatched close keypoints;
   recent points that are rarely found are culled.
6. **Relocalisation** when lost: descriptor matching against every keyframe, the best-matching
   ones (ORB-SLAM2 ranks its keyframe database by bag-of-words score) tried with PnP-RANSAC, then
   local-map tracking.

Keypoints flagged dynamic are never matched and never create map points.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np

from ..checks import check_numbers
from ..frontend.matching import Matches, guided_match, hamming
from ..frontend.orb import Features, OrbExtractor
from ..geometry import from_rvec, invert, project, rotation_angle_deg, to_rvec, transform
from ..mapping.slam_map import KeyFrame, SlamMap
from .pose import CHI2_MONO, CHI2_STEREO, chi2, observations, optimise_pose
from .rolling_shutter import readout_of, twist, unroll

SAMPLERS = ("ransac", "prosac")
"""Values of :attr:`TrackerConfig.sampler`."""
POLICIES = ("orbslam2", "harness")
"""Values of :attr:`TrackerConfig.policy`: how frames are tracked and keyframes chosen."""


@dataclass(frozen=True)
class TrackerConfig:
    """Tracking settings (defaults follow ORB-SLAM2's RGB-D tracking where it has one)."""

    init_min_points: int = 100
    """Close, static keypoints needed to create the first keyframe."""
    search_radius: float = 7.0
    """Window around a prediction for motion-model matching, px at level 0 (ORB-SLAM2: 7)."""
    local_radius: float = 4.0
    """Window for local-map matching after the pose is known, px at level 0 (ORB-SLAM2: 4)."""
    max_hamming: int = 100
    ratio: float = 0.8
    min_matches: int = 20
    """Fewer motion-model matches than this: search again with a doubled window."""
    min_inliers: int = 30
    """Fewest inliers after local-map tracking for the frame to count as tracked (ORB-SLAM2: 30)."""
    ransac_iterations: int = 100
    ransac_threshold: float = 3.0
    """PnP-RANSAC reprojection threshold, px (refinement then uses the per-level χ² test)."""
    sampler: str = "ransac"
    """How PnP hypotheses are sampled: ``ransac`` (uniformly, ``cv2.solvePnPRansac`` with
    AP3P / EPnP seeded with the prediction) or ``prosac`` (OpenCV's USAC with PROSAC sampling,
    ``cv2.UsacParams``: the matches sorted by descriptor distance, the most distinctive tried
    first)."""
    refine_rounds: int = 4
    rgbd_refinement: bool = True
    """Refine with depth as a virtual stereo coordinate (ORB-SLAM2 RGB-D); False = reprojection
    error only (``cv2.solvePnPRefineLM``)."""
    virtual_baseline: float = 0.075
    """Baseline of the virtual stereo pair, metres (ORB-SLAM2's TUM ``bf`` = 40 = 535.4 × 0.075)."""
    policy: str = "orbslam2"
    """``orbslam2``: ORB-SLAM2's RGB-D ``Tracking`` (the motion model matches the last frame's
    map points and its visual-odometry points, back-projected from its depth, and optimises the
    predicted pose with the robust χ² rounds of ``PoseOptimization``; a keyframe whenever
    ``NeedNewKeyFrame``'s ``c2`` holds, with map points from its close keypoints as
    ``CreateNewKeyFrame``; the default); ``harness``: PnP-RANSAC on the projected local map and
    the sparser keyframe rule of step 5."""
    th_depth: float = 3.0
    """``orbslam2``: close / far depth bound, metres (ORB-SLAM2's ``ThDepth`` 40 × the TUM
    baseline bf / fx = 0.075 m)."""
    min_new_points: int = 100
    """``orbslam2``: a keyframe (and the last frame's visual odometry) creates points from all
    its close keypoints and at least this many of the nearest (ORB-SLAM2: 100)."""
    keyframe_min_frames: int = 0
    """``orbslam2``: frames between keyframes at least (ORB-SLAM2's ``mMinFrames``: 0; its local
    mapping is always idle here, the harness's back end runs between frames)."""
    motion_ransac: bool = True
    """``orbslam2``: seed the motion model's pose optimisation with PnP-RANSAC on its matches
    instead of the constant-velocity prediction (not ORB-SLAM2's; on by default, since without
    it the policy diverges on synthetic static scenes and on real ``freiburg1_rpy`` frames)."""
    reference_keyframe: bool = True
    """Without a motion model (the second frame, the first after a relocalisation) match the
    reference keyframe by descriptor, as ORB-SLAM2 (``TrackReferenceKeyFrame``); False = project
    the local map with the last pose, as the harness did before."""
    local_keyframes: int = 10
    keyframe_ratio: float = 0.75
    """New keyframe when inliers < this × the reference keyframe's tracked points (ORB-SLAM2 RGB-D)."""
    min_close_tracked: int = 100
    min_close_untracked: int = 70
    max_keyframe_interval: int = 30
    keyframe_translation: float = 0.15
    """New keyframe when the camera moved this far from the reference keyframe, metres."""
    keyframe_rotation_deg: float = 15.0
    """New keyframe when the camera turned this much from the reference keyframe, degrees."""
    min_found_ratio: float = 0.25
    min_observations: int = 2
    reloc_keyframes: int = 6
    """Relocalisation tries the keyframes with the most descriptor matches, this many at most."""
    reloc_ratio: float = 0.75
    reloc_max_hamming: int = 64
    reloc_min_inliers: int = 50
    readout: float | None = None
    """Rolling-shutter readout of the colour camera, seconds from the top row to the bottom row:
    keypoints are moved to where they would be at the frame's stamp (:mod:`.rolling_shutter`).
    None = the camera's declared ``readout`` (``intrinsics.yaml``; TUM's fr1 / fr2 / fr3
    cameras 0.03), and no correction when it declares none; 0 = off."""
    reloc_recent_frames: int = 30
    """For this many frames after a relocalisation, tracking needs ``reloc_min_inliers`` inliers
    instead of ``min_inliers`` (ORB-SLAM2's ``TrackLocalMap``: 50 within ``mMaxFrames`` = the
    frame rate after ``mnLastRelocFrameId``); 0 = off."""

    def __post_init__(self) -> None:
        # Messages start with the field name: uss-slam prefixes the config section.
        if self.sampler not in SAMPLERS:
            raise ValueError(f"sampler must be one of {', '.join(SAMPLERS)}, got {self.sampler!r}")
        if self.policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {self.policy!r}")
        if self.readout is not None and self.readout >= 1:
            raise ValueError(f"readout must be < 1 s (a frame's readout), got {self.readout}")
        check_numbers(
            self,
            positive=(
                "search_radius",
                "local_radius",
                "ransac_threshold",
                "virtual_baseline",
                "ransac_iterations",
                "refine_rounds",
                "local_keyframes",
                "reloc_keyframes",
                "max_keyframe_interval",
                "th_depth",
            ),
            unit=("ratio", "keyframe_ratio", "reloc_ratio", "min_found_ratio"),
        )


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
        self, config: TrackerConfig, extractor: OrbExtractor, sampling_seed: int | None = None
    ) -> None:
        """``sampling_seed``: None = RANSAC draws its samples as OpenCV does for the given
        matches (deterministic); an integer perturbs the sampling reproducibly, for repeated
        runs (:meth:`_sampling_order`)."""
        self.config = config
        self._rng = None if sampling_seed is None else np.random.default_rng(sampling_seed)
        self.extractor = extractor
        self.camera = extractor.camera
        self.k = extractor.camera.matrix
        self.size = (extractor.camera.width, extractor.camera.height)
        self.sigma2 = extractor.sigma2
        self.bf = extractor.camera.fx * config.virtual_baseline
        self.map = SlamMap(extractor.config.scale_factor, extractor.config.n_levels)
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
        """Frame index of the latest relocalisation."""
        self.lost_events = 0
        self._current_index = 0
        self._last_frame: tuple[Features, np.ndarray, np.ndarray] | None = None
        """``policy=orbslam2``: the last tracked frame's features, its map point per keypoint
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
                and self._recently_relocalised(frame_index)
                and int((matched >= 0).sum()) < self.config.reloc_min_inliers
            ):
                pose_cw = None
        if pose_cw is None:
            if self.state is TrackingState.OK:
                self.lost_events += 1
            self.state = TrackingState.LOST
            pose_cw, matched = self._relocalise(features, static)
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
    ) -> tuple[np.ndarray, np.ndarray]:
        """Re-estimate a tracked pose without the keypoints the post-pose filters flagged.

        ``drop`` (N,) bool. Returns ``(pose_wc, matched)`` with the dropped keypoints unmatched;
        the pose is kept when fewer than ``min_inliers`` matches would remain.
        """
        keep = (matched >= 0) & ~drop
        if not np.any(drop & (matched >= 0)) or keep.sum() < self.config.min_inliers:
            matched = np.where(drop, -1, matched)
            return pose_wc, matched
        pose_cw, out = self._refine_matches(invert(pose_wc), features, matched, keep)
        return invert(pose_cw), out

    def _refine_matches(
        self, pose_cw: np.ndarray, features: Features, matched: np.ndarray, keep: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`refine_pose` on the matches ``keep`` (N,) bool selects: ``(pose_cw, matched)``
        with only the inliers of the refinement matched."""
        kp = np.flatnonzero(keep)
        pose_cw, inl = self.refine_pose(
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
            create = (~dynamic) & features.has_depth & ~good
            if self.config.policy == "orbslam2":
                create = self._new_points(features, good, ~dynamic)
            kf = self.map.add_keyframe(
                frame_index, stamp, result.pose_wc, features, matched, dynamic, create
            )
            self.map.cull(self.config.min_found_ratio, self.config.min_observations)
            self.frames_since_keyframe = 0
            result.new_keyframe = kf
            matched = kf.point_ids
        else:
            self.frames_since_keyframe += 1
        self._accept(pose_cw, stamp, matched[matched >= 0], kf)
        if self.config.policy == "orbslam2":
            usable = np.zeros(len(features), bool) if kf is not None else ~dynamic
            self._last_frame = (features, matched, usable)
        return kf

    def _recently_relocalised(self, frame_index: int) -> bool:
        last = self.last_relocalisation
        return last is not None and frame_index < last + self.config.reloc_recent_frames

    @property
    def initialized(self) -> bool:
        """The first keyframe exists (before that, every frame is a first-keyframe candidate)."""
        return self.state is not TrackingState.NOT_INITIALIZED

    def wants_keyframe(self, result: TrackResult, features: Features, dynamic: np.ndarray) -> bool:
        """Would :meth:`finish_frame` insert this tracked frame as a keyframe (module docstring,
        step 5)? False for untracked frames and for the first keyframe, already inserted."""
        if result.pose_wc is None or result.new_keyframe is not None:
            return False
        return self._need_keyframe(result.pose_wc, features, result.matched, dynamic)

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

    def _project(self, point_ids: np.ndarray, pose_cw: np.ndarray):
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

    def match_projected(
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
        ids, uv, level, cos_view = self._project(point_ids, pose_cw)
        r = radius * self.extractor.scales[level]
        if local:
            self.map.points.visible.view[ids] += 1
            # ORB-SLAM2 narrows the local-map window for near-frontal views (RadiusByViewingCos).
            r = r * np.where(cos_view > 0.998, 0.625, 1.0)
        pts = self.map.points
        descriptors = (pts.descriptor.view[ids], pts.latest_descriptor.view[ids])
        return ids, self._guided(uv, r, level, descriptors, features, available)

    def _guided(self, uv, radius, level, descriptors, features: Features, available) -> Matches:
        """:func:`guided_match` of projections to ``features`` with this tracker's limits."""
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

    def _track_motion(self, features: Features, static: np.ndarray):
        cfg = self.config
        if self.velocity is None and cfg.reference_keyframe and self.reference is not None:
            tracked = self._track_reference(features, static)
            if tracked[0] is not None:
                return tracked
        if cfg.policy == "orbslam2" and self.velocity is not None:
            return self._track_last_frame(features, static)
        velocity = self.velocity if self.velocity is not None else np.eye(4)
        predicted = velocity @ self.last_pose_cw
        local = self._local_points()
        ids, m = self.match_projected(local, predicted, features, static, cfg.search_radius)
        if len(m) < cfg.min_matches:
            ids, m = self.match_projected(local, predicted, features, static, 2 * cfg.search_radius)
        if len(m) < cfg.min_matches:
            return None, None
        pose_cw = self._pnp(
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
        """ORB-SLAM2's ``TrackWithMotionModel`` + ``TrackLocalMap`` (``policy=orbslam2``).

        The last frame's map points and its visual-odometry points (``UpdateLastFrame``: its
        unmatched close keypoints back-projected with its pose, when it is not a keyframe) are
        projected with the constant-velocity prediction and matched in a window of
        ``search_radius`` (twice that below ``min_matches``; fewer: the reference keyframe is
        tried, then relocalisation); the pose is optimised from the prediction with every match
        an inlier at first (:meth:`optimise_all`), ≥ 10 map-point inliers needed; the local map
        then adds its matches and the pose is optimised again on all of them. The visual-odometry
        points steer the pose but are never map points: a walker's keypoints of the last frame
        are such points, re-created on every frame, which is how walkers fool ORB-SLAM2."""
        cfg = self.config
        assert self.velocity is not None and self.last_pose_cw is not None
        predicted = self.velocity @ self.last_pose_cw
        world, desc, level, map_ids = self._last_frame_points()
        for radius in (cfg.search_radius, 2 * cfg.search_radius):
            query, kp = self._match_points(world, desc, level, predicted, features, static, radius)
            if len(query) >= cfg.min_matches:
                break
        else:
            return self._track_reference_or_lost(features, static)
        if cfg.motion_ransac:
            ransac = self._pnp(world[query], features, kp, predicted, np.zeros(len(kp)))
            if ransac is None:
                return self._track_reference_or_lost(features, static)
            predicted = ransac
        pose_cw, inl = self.optimise_all(world[query], features, kp, predicted)
        if int((inl & (map_ids[query] >= 0)).sum()) < 10:
            return self._track_reference_or_lost(features, static)
        query, kp = query[inl], kp[inl]
        return self._track_local_map_vo(pose_cw, features, static, world[query], map_ids[query], kp)

    def _track_reference_or_lost(self, features: Features, static: np.ndarray):
        if self.config.reference_keyframe and self.reference is not None:
            return self._track_reference(features, static)
        return None, None

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
        vo = self._nearest_close(feats, np.flatnonzero(usable & ~has & feats.has_depth), len(own))
        pose_wc = invert(self.last_pose_cw)
        world = np.concatenate(
            [pts.position.view[ids[own]], transform(pose_wc, feats.points[vo])], axis=0
        )
        desc = np.concatenate([pts.descriptor.view[ids[own]], feats.descriptors[vo]], axis=0)
        level = np.concatenate([feats.octave[own], feats.octave[vo]])
        map_ids = np.concatenate([ids[own], np.full(len(vo), -1, np.int64)])
        return world, desc, level, map_ids

    def _match_points(self, world, desc, level, pose_cw, features, available, radius):
        """Points ``world`` (with their descriptors and the level they were seen at) projected
        with ``pose_cw`` and matched to the ``available`` keypoints within ``radius`` × their
        level's scale (ORB-SLAM2's frame-to-frame ``SearchByProjection``): ``(query, keypoint)``
        index arrays."""
        cam = transform(pose_cw, world)
        w, h = self.size
        front = cam[:, 2] > 1e-6
        uv = project(self.k, np.where(front[:, None], cam, 1.0))
        inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        q = np.flatnonzero(inside)
        radii = radius * self.extractor.scales[level[q]]
        m = self._guided(uv[q], radii, level[q], (desc[q],), features, available)
        return q[m.query], m.keypoint

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
        ids, m = self.match_projected(local, pose_cw, features, free, cfg.local_radius, local=True)
        world = np.concatenate([world, self.map.points.position.view[ids[m.query]]], axis=0)
        map_ids = np.concatenate([map_ids, ids[m.query]])
        kp = np.concatenate([kp, m.keypoint])
        pose_cw, inl = self.optimise_all(world, features, kp, pose_cw)
        good = inl & (map_ids >= 0)
        if good.sum() < cfg.min_inliers:
            return None, None
        matched = np.full(len(features), -1, np.int64)
        matched[kp[good]] = map_ids[good]
        return pose_cw, matched

    def optimise_all(
        self, world: np.ndarray, features: Features, kp: np.ndarray, pose_cw: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """ORB-SLAM2's ``PoseOptimization``: every match starts as an inlier; four rounds, each
        optimising from ``pose_cw`` on the current inliers (Huber kernel in the first three)
        and re-classifying every match by the χ² test. Returns ``(pose_cw, inlier mask)``."""
        uv = features.uv[kp]
        inv_sigma2 = 1.0 / self.sigma2[features.octave[kp]]
        obs, stereo = observations(uv, features.depth[kp], self.bf)
        inl = np.ones(len(kp), bool)
        start, pose = pose_cw, pose_cw
        for round_ in range(4):
            if inl.sum() < 6:
                break
            pose = optimise_pose(
                self.k, self.bf, start, world[inl], obs[inl], stereo[inl], inv_sigma2[inl],
                robust=round_ < 3,
            )  # fmt: skip
            inl = self._inliers(world, obs, stereo, inv_sigma2, pose)
        return pose, inl

    def _track_reference(self, features: Features, static: np.ndarray):
        """ORB-SLAM2's ``TrackReferenceKeyFrame``, for a frame without a motion model (the
        second frame, the first after a relocalisation): the static keypoints matched to the
        reference keyframe's map points by descriptor (ratio 0.7, no projection window), at
        least 15 matches, PnP-RANSAC seeded with the last pose, then local-map tracking.
        Projecting with the last pose instead misses the matches of a camera that already
        moves fast when tracking starts (a hand-held Kinect turning at 1.5 rad/s moves the
        image ~25 px per frame, beyond twice the 7 px window)."""
        assert self.reference is not None
        found = self.match_keyframe(
            features, np.flatnonzero(static), self.reference, 0.7, self.config.max_hamming, 15
        )
        if found is None or len(found[0]) < 15:
            return None, None
        kp, pid, distance = found
        pose_cw = self._pnp(
            self.map.points.position.view[pid], features, kp, self.last_pose_cw, distance
        )
        if pose_cw is None:
            return None, None
        return self._track_local_map(self._local_points(), pose_cw, features, static)

    def _track_local_map(
        self, local: np.ndarray, pose_cw: np.ndarray, features: Features, static: np.ndarray
    ):
        ids, m = self.match_projected(
            local, pose_cw, features, static, self.config.local_radius, local=True
        )
        if len(m) < self.config.min_inliers:
            return None, None
        pose_cw, inl = self.refine_pose(
            self.map.points.position.view[ids[m.query]], features, m.keypoint, pose_cw
        )
        if inl.sum() < self.config.min_inliers:
            return None, None
        matched = np.full(len(features), -1, np.int64)
        matched[m.keypoint[inl]] = ids[m.query[inl]]
        return pose_cw, matched

    def _pnp(
        self,
        world: np.ndarray,
        features: Features,
        kp: np.ndarray,
        guess_cw: np.ndarray | None,
        distance: np.ndarray,
    ) -> np.ndarray | None:
        cfg = self.config
        if len(world) < 6:
            return None
        if cfg.sampler == "prosac":
            ok, rvec, tvec, inliers = self._prosac(world, features, kp, distance)
            found = self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inliers, 6)
            return None if found is None else found[0]
        ok, rvec, tvec, inliers = self._ransac(
            world, features.uv[kp], cfg.ransac_iterations, guess_cw
        )
        found = self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inliers, 6)
        return None if found is None else found[0]

    def _ransac(
        self,
        world: np.ndarray,
        uv: np.ndarray,
        iterations: int,
        guess_cw: np.ndarray | None = None,
    ):
        """OpenCV's PnP-RANSAC of ``world[i] <-> uv[i]``, the matches in
        :meth:`_sampling_order`: AP3P minimal sets, or EPnP starting from the pose ``guess_cw``
        when given. Returns ``(ok, rvec, tvec, inliers)``."""
        if guess_cw is not None:
            rvec, tvec = to_rvec(guess_cw)
            use_guess = True
        else:
            rvec, tvec = np.zeros((3, 1)), np.zeros((3, 1))
            use_guess = False
        order = self._sampling_order(len(world))
        return cv2.solvePnPRansac(
            world[order].reshape(-1, 1, 3).astype(np.float64),
            uv[order].reshape(-1, 1, 2).astype(np.float64),
            self.k,
            None,
            rvec,
            tvec,
            useExtrinsicGuess=use_guess,
            iterationsCount=iterations,
            reprojectionError=self.config.ransac_threshold,
            confidence=0.999,
            flags=cv2.SOLVEPNP_EPNP if use_guess else cv2.SOLVEPNP_AP3P,
        )

    def _prosac(
        self,
        world: np.ndarray,
        features: Features,
        kp: np.ndarray,
        distance: np.ndarray,
        iterations: int | None = None,
    ):
        """PnP with OpenCV's USAC and PROSAC sampling: matches sorted by descriptor distance
        (PROSAC draws its samples from the best-ranked matches first). USAC's local optimisation
        and final polishing are off: the RGB-D refinement that follows does that work (with
        them, ``flags=cv2.USAC_PROSAC``, a call costs about 4 ms of CPU instead of 0.8 ms for
        300 matches). Returns ``(ok, rvec, tvec, inliers)``, inlier indices in sorted order."""
        order = np.argsort(distance, kind="stable")
        params = cv2.UsacParams()
        params.sampler = cv2.SAMPLING_PROSAC
        params.loMethod = cv2.LOCAL_OPTIM_NULL
        params.final_polisher = cv2.NONE_POLISHER
        params.maxIterations = int(iterations or self.config.ransac_iterations)
        params.threshold = self.config.ransac_threshold
        params.confidence = 0.999
        if self._rng is not None:  # USAC seeds its own generator: give it a drawn state
            params.randomGeneratorState = int(self._rng.integers(1, 2**31))
        ok, _, rvec, tvec, inliers = cv2.solvePnPRansac(
            world[order].reshape(-1, 1, 3).astype(np.float64),
            features.uv[kp[order]].reshape(-1, 1, 2).astype(np.float64),
            self.k,
            None,
            params=params,
        )
        return ok, rvec, tvec, inliers

    def _sampling_order(self, n: int) -> np.ndarray | slice:
        """The order in which ``n`` matches are handed to OpenCV's RANSAC: as given (no seed),
        or a seeded random permutation. OpenCV's RANSAC seeds its generator with a constant, so
        the samples it draws are fixed by the order of the matches; permuting them draws other
        minimal sets, a perturbation of the sampling alone (the inliers and the refined pose are
        computed on the matches in their given order)."""
        return slice(None) if self._rng is None else self._rng.permutation(n)

    def _refined_hypothesis(
        self, world, features, kp, ok, rvec, tvec, inliers, min_inliers: int
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The RANSAC pose refined (:meth:`refine_pose`) and its inlier mask over the given
        matches (in their given order), or None with too few inliers."""
        if not ok or inliers is None or len(inliers) < min_inliers:
            return None
        pose_cw, inl = self.refine_pose(world, features, kp, from_rvec(rvec, tvec))
        return (pose_cw, inl) if inl.sum() >= min_inliers else None

    def refine_pose(
        self, world: np.ndarray, features: Features, kp: np.ndarray, pose_cw: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Refine a pose on matches ``world[i] <-> keypoint kp[i]``; returns ``(pose_cw, inliers)``.

        ``refine_rounds`` rounds, each re-classifying inliers by the χ² test (ORB-SLAM2): with
        ``rgbd_refinement`` the RGB-D Gauss–Newton of :mod:`.pose` (depth as a virtual stereo
        coordinate), else OpenCV's ``solvePnPRefineLM`` on the reprojection error alone.
        """
        cfg = self.config
        uv = features.uv[kp]
        inv_sigma2 = 1.0 / self.sigma2[features.octave[kp]]
        depth = features.depth[kp] if cfg.rgbd_refinement else np.zeros(len(kp), np.float32)
        obs, stereo = observations(uv, depth, self.bf)
        inl = self._inliers(world, obs, stereo, inv_sigma2, pose_cw)
        for _ in range(cfg.refine_rounds):
            if inl.sum() < 6:
                break
            if cfg.rgbd_refinement:
                pose_cw = optimise_pose(
                    self.k, self.bf, pose_cw, world[inl], obs[inl], stereo[inl], inv_sigma2[inl]
                )
            else:
                rvec, tvec = to_rvec(pose_cw)
                rvec, tvec = cv2.solvePnPRefineLM(
                    world[inl].reshape(-1, 1, 3),
                    uv[inl].reshape(-1, 1, 2),
                    self.k,
                    None,
                    rvec,
                    tvec,
                )
                pose_cw = from_rvec(rvec, tvec)
            new = self._inliers(world, obs, stereo, inv_sigma2, pose_cw)
            if np.array_equal(new, inl):
                break
            inl = new
        return pose_cw, inl

    def _inliers(
        self,
        world: np.ndarray,
        obs: np.ndarray,
        stereo: np.ndarray,
        inv_sigma2: np.ndarray,
        pose_cw: np.ndarray,
    ) -> np.ndarray:
        e2, front = chi2(self.k, self.bf, pose_cw, world, obs, stereo, inv_sigma2)
        return front & (e2 < np.where(stereo, CHI2_STEREO, CHI2_MONO))

    # ------------------------------------------------------------------ relocalisation

    def _relocalise(self, features: Features, static: np.ndarray):
        """ORB-SLAM2's relocalisation without its bag of words: every keyframe of the map is a
        candidate, scored by how many of the frame's static descriptors match its map points
        (ratio test); the ``reloc_keyframes`` best are tried in that order (PnP-RANSAC, then
        local-map tracking, ``reloc_min_inliers`` needed). ORB-SLAM2 likewise queries its whole
        keyframe database: after a long occlusion the keyframes near the last known pose may be
        the ones taken while the view was blocked, holding few of the points now in view."""
        cfg = self.config
        kfs = self.map.keyframes
        if not kfs or static.sum() < cfg.min_inliers:
            return None, None
        query = np.flatnonzero(static)
        scored: list[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]] = []
        for k, kf in enumerate(kfs):
            found = self.match_keyframe(
                features, query, kf, cfg.reloc_ratio, cfg.reloc_max_hamming, cfg.min_inliers
            )
            if found is not None and len(found[0]) >= cfg.min_matches:
                scored.append((len(found[0]), k, *found))
        # Most matches first; ties: the latest keyframe first.
        scored.sort(key=lambda c: (-c[0], -c[1]))
        for _, k, kp, pid, distance in scored[: cfg.reloc_keyframes]:
            found = self.pnp_global(self.map.points.position.view[pid], features, kp, distance)
            if found is None:
                continue
            pose_cw = found[0]
            local = self.map.points_of(
                np.union1d(
                    [k],
                    np.argsort(-self.map.covisibility(pid))[: cfg.local_keyframes],
                ).astype(np.int64)
            )
            pose2, matched = self._track_local_map(local, pose_cw, features, static)
            if pose2 is not None and (matched >= 0).sum() >= cfg.reloc_min_inliers:
                return pose2, matched
        return None, None

    def match_keyframe(
        self,
        features: Features,
        query: np.ndarray,
        kf: KeyFrame,
        ratio: float,
        max_hamming: int,
        min_points: int,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Keypoints ``query`` of ``features`` matched to the good map points of a keyframe by
        descriptor (nearest neighbour in Hamming distance among the keyframe's keypoints that
        hold one, ratio test, at most ``max_hamming``), one keypoint per map point: ``(keypoint
        indices, map point ids, distances)``; None when the keyframe holds fewer than
        ``min_points`` good points or there is nothing to query (a frame without keypoints)."""
        ids = kf.point_ids
        usable = np.flatnonzero((ids >= 0) & ~self.map.points.bad.view[np.maximum(ids, 0)])
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
        # Keep one keypoint per map point (the first, i.e. arbitrary but deterministic).
        _, first = np.unique(pid, return_index=True)
        return kp[first], pid[first], dist[good, 0][first]

    def pnp_global(
        self, world: np.ndarray, features: Features, kp: np.ndarray, distance: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Pose of a frame from matches ``world[i] <-> keypoint kp[i]`` (Hamming ``distance``)
        without a prior (relocalisation, loop verification): PnP-RANSAC (or PROSAC) and the
        RGB-D refinement, 10 inliers needed. Returns ``(pose_cw, inlier mask)`` or None."""
        if self.config.sampler == "prosac":
            iterations = max(self.config.ransac_iterations, 300)
            ok, rvec, tvec, inl = self._prosac(world, features, kp, distance, iterations)
            return self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inl, 10)
        ok, rvec, tvec, inliers = self._ransac(
            world, features.uv[kp], max(self.config.ransac_iterations, 300)
        )
        return self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inliers, 10)

    # ------------------------------------------------------------------ keyframes

    def _need_keyframe(
        self, pose_wc: np.ndarray, features: Features, matched: np.ndarray, dynamic: np.ndarray
    ) -> bool:
        """The keyframe decision of step 5 (module docstring).

        This rule is why unfiltered walkers fool the harness far less than ORB-SLAM3: map points
        come only from keyframes, and with keyframes this sparse (15 in 300 frames of
        ``walking_xyz``) a walker has mostly moved out of the χ² bound of its points by the time
        they are matched again, whereas ORB-SLAM3 (127 keyframes) re-creates them every few
        frames and keeps them as inliers (forcing a keyframe on every frame,
        ``max_keyframe_interval=1``, raises the ATE from 7.8 to 167 mm and the share of inliers
        on people from 2.4% to 13.6%; ``benchmarks/slam_walker_inliers.py``).
        """
        cfg = self.config
        ref = self.reference
        if ref is None:
            return True
        if cfg.policy == "orbslam2":
            return self._need_keyframe_orbslam2(features, matched, dynamic)
        inliers = int((matched >= 0).sum())
        if inliers <= 15:
            return False  # too weak to seed a keyframe (ORB-SLAM2's c2 lower bound)
        min_obs = 3 if len(self.map.keyframes) > 2 else 2
        ref_ids = ref.point_ids[ref.point_ids >= 0]
        pts = self.map.points
        ref_ids = ref_ids[~pts.bad.view[ref_ids]]
        ref_tracked = int((pts.observations.view[ref_ids] >= min_obs).sum())
        close = features.has_depth & ~dynamic
        tracked_close = int((close & (matched >= 0)).sum())
        untracked_close = int((close & (matched < 0)).sum())
        need_close = (
            tracked_close < cfg.min_close_tracked and untracked_close > cfg.min_close_untracked
        )
        weak = inliers < cfg.keyframe_ratio * ref_tracked or need_close
        rel = invert(ref.pose_wc) @ pose_wc
        moved = (
            np.linalg.norm(rel[:3, 3]) > cfg.keyframe_translation
            or rotation_angle_deg(rel[:3, :3]) > cfg.keyframe_rotation_deg
        )
        stale = self.frames_since_keyframe + 1 >= cfg.max_keyframe_interval
        return weak or moved or stale

    def _need_keyframe_orbslam2(
        self, features: Features, matched: np.ndarray, dynamic: np.ndarray
    ) -> bool:
        """ORB-SLAM2's ``NeedNewKeyFrame`` (RGB-D): not within ``max_keyframe_interval`` frames
        of a relocalisation (once the map holds more keyframes than that); otherwise a keyframe
        when ``(c1a or c1b or c1c) and c2``: c2 = fewer inliers than ``keyframe_ratio`` (0.4
        with one keyframe) × the reference keyframe's points seen by two keyframes or more (one,
        while the map holds two keyframes or fewer; ORB-SLAM2 counts an RGB-D observation
        twice), or too few close points tracked (< ``min_close_tracked``) while many are not
        (> ``min_close_untracked``), with more than 15 inliers; c1a = ``max_keyframe_interval``
        frames since the last keyframe, c1b = ``keyframe_min_frames`` frames and local mapping
        idle (always, here), c1c = inliers below a quarter of the reference's or the close rule."""
        cfg = self.config
        ref = self.reference
        assert ref is not None
        n_kfs = len(self.map.keyframes)
        index = self._current_index
        if (
            self.last_relocalisation is not None
            and index < self.last_relocalisation + cfg.max_keyframe_interval
            and n_kfs > cfg.max_keyframe_interval
        ):
            return False
        min_obs = 2 if n_kfs > 2 else 1
        ids = ref.point_ids[ref.point_ids >= 0]
        pts = self.map.points
        ids = ids[~pts.bad.view[ids]]
        ref_tracked = int((pts.observations.view[ids] >= min_obs).sum())
        inliers = int((matched >= 0).sum())
        close = (features.depth > 0) & (features.depth < cfg.th_depth) & ~dynamic
        tracked_close = int((close & (matched >= 0)).sum())
        untracked_close = int((close & (matched < 0)).sum())
        need_close = (
            tracked_close < cfg.min_close_tracked and untracked_close > cfg.min_close_untracked
        )
        ratio = cfg.keyframe_ratio if n_kfs >= 2 else 0.4
        since = self.frames_since_keyframe + 1
        c1a = since >= cfg.max_keyframe_interval
        c1b = since >= cfg.keyframe_min_frames
        c1c = inliers < 0.25 * ref_tracked or need_close
        c2 = (inliers < ratio * ref_tracked or need_close) and inliers > 15
        return (c1a or c1b or c1c) and c2

    def _new_points(
        self, features: Features, tracked: np.ndarray, static: np.ndarray
    ) -> np.ndarray:
        """ORB-SLAM2's ``CreateNewKeyFrame`` (RGB-D): the static keypoints with depth, nearest
        first, get a map point unless they are tracked, until past ``th_depth`` with
        ``min_new_points`` counted (tracked ones included). Returns the boolean mask."""
        chosen = self._nearest_close(features, np.flatnonzero(static & features.has_depth), 0)
        create = np.zeros(len(features), bool)
        create[chosen[~tracked[chosen]]] = True
        return create

    def _nearest_close(self, features: Features, candidates: np.ndarray, counted: int):
        """ORB-SLAM2's choice of points from depth (``CreateNewKeyFrame``, ``UpdateLastFrame``):
        the ``candidates`` nearest first, every one within ``th_depth`` and the nearest ones
        beyond it until ``min_new_points`` are counted (``counted`` already are)."""
        order = candidates[np.argsort(features.depth[candidates], kind="stable")]
        keep = (features.depth[order] <= self.config.th_depth) | (
            np.arange(len(order)) + counted < self.config.min_new_points
        )
        return order[keep]


__all__ = ["TrackResult", "Tracker", "TrackerConfig", "TrackingState", "hamming"]

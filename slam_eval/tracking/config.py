"""Tracking settings: :class:`TrackerConfig`, the ``slam.tracker`` config section."""

from __future__ import annotations

from dataclasses import dataclass

from uss_slam.core.schema import check_fields, ranged

SAMPLERS = ("ransac", "prosac")
"""Values of :attr:`TrackerConfig.sampler`."""
REMOVED = {
    "policy": "the harness tracking policy was removed (ORB-SLAM2's is the only one); "
    "commit 0fea5f3 reproduces the figures made with slam.tracker.policy=harness",
    "keyframe_translation": "the harness policy's keyframe rule was removed; "
    "commit 0fea5f3 reproduces the figures made with it",
    "keyframe_rotation_deg": "the harness policy's keyframe rule was removed; "
    "commit 0fea5f3 reproduces the figures made with it",
}
"""Keys of ``slam.tracker`` that no longer exist, with why: what an old override is told."""


@dataclass(frozen=True)
class TrackerConfig:
    """Tracking settings (defaults follow ORB-SLAM2's RGB-D tracking where it has one)."""

    init_min_points: int = ranged(100, min=0)
    """Close, static keypoints needed to create the first keyframe."""
    search_radius: float = ranged(15.0, gt=0)
    """Window around a prediction for motion-model matching, px at level 0 (ORB-SLAM2's
    ``TrackWithMotionModel``: 15 for RGB-D and monocular, 7 for stereo only). A narrower window
    lets a frame whose motion the constant-velocity model underestimates settle on a pose between
    the prediction and the truth: 7 px left one frame of ``freiburg1_rpy`` at every 3rd frame
    (11.8° of turn) 6° off in 4 of 5 repeats."""
    local_radius: float = ranged(12.0, gt=0)
    """Window for local-map matching after the pose is known, px at level 0, 0.625× for
    near-frontal views (ORB-SLAM2's ``SearchLocalPoints``: ``RadiusByViewingCos`` 4 × th 3 for
    RGB-D)."""
    max_hamming: int = ranged(100, min=0, max=256)
    ratio: float = ranged(0.8, gt=0, max=1)
    min_matches: int = ranged(20, min=0)
    """Fewer motion-model matches than this: search again with a doubled window."""
    min_inliers: int = ranged(30, min=0)
    """Fewest inliers after local-map tracking for the frame to count as tracked (ORB-SLAM2: 30)."""
    ransac_iterations: int = ranged(100, min=1)
    ransac_threshold: float = ranged(3.0, gt=0)
    """PnP-RANSAC reprojection threshold, px (refinement then uses the per-level χ² test)."""
    sampler: str = ranged("ransac", choices=SAMPLERS)
    """How PnP hypotheses are sampled: ``ransac`` (uniformly, ``cv2.solvePnPRansac`` with
    AP3P / EPnP seeded with the prediction) or ``prosac`` (OpenCV's USAC with PROSAC sampling,
    ``cv2.UsacParams``: the matches sorted by descriptor distance, the most distinctive tried
    first)."""
    refine_rounds: int = ranged(4, min=1)
    rgbd_refinement: bool = True
    """Refine with depth as a virtual stereo coordinate (ORB-SLAM2 RGB-D); False = reprojection
    error only (``cv2.solvePnPRefineLM``)."""
    pose_tolerance: float = ranged(1e-5, gt=0, max=1e-3)
    """The pose-only optimisation (Gauss–Newton) stops once a step moves the pose by less than
    this in every component, metres and radians (1e-5: 0.005 px at fx 525, far below a pose's
    noise), or after 10 steps (ORB-SLAM2's ``PoseOptimization``: 10 Levenberg–Marquardt
    iterations in each of its 4 rounds, no tolerance). 1e-5 since 2026-12-07 (1e-7 before),
    with local BA's 2 iterations: docs/results/slam.md, "two convergence cuts for speed"."""
    virtual_baseline: float = ranged(0.075, gt=0)
    """Baseline of the virtual stereo pair, metres (ORB-SLAM2's TUM ``bf`` = 40 = 535.4 × 0.075)."""
    th_depth: float = ranged(3.0, gt=0)
    """Close / far depth bound, metres (ORB-SLAM2's ``ThDepth`` 40 × the TUM
    baseline bf / fx = 0.075 m)."""
    min_new_points: int = ranged(100, min=0)
    """A keyframe (and the last frame's visual odometry) creates points from all
    its close keypoints and at least this many of the nearest (ORB-SLAM2: 100)."""
    keyframe_min_frames: int = ranged(0, min=0)
    """Frames between keyframes at least (ORB-SLAM2's ``mMinFrames``: 0; its local
    mapping is always idle here: the back end runs between frames)."""
    motion_ransac: bool = True
    """Seed the motion model's pose optimisation with PnP-RANSAC on its matches
    instead of the constant-velocity prediction (not ORB-SLAM2's; on by default, since without
    it tracking diverges on synthetic static scenes and on real ``freiburg1_rpy`` frames)."""
    reference_keyframe: bool = True
    """Without a motion model (the second frame, the first after a relocalisation) match the
    reference keyframe by descriptor, as ORB-SLAM2 (``TrackReferenceKeyFrame``); False = project
    the local map with the last pose."""
    check_orientation: bool = True
    """Keep only matches of a consistent image rotation when matching the last frame by
    projection, the reference keyframe and relocalisation candidates by descriptor (ORB-SLAM2's
    ``mbCheckOrientation`` rotation histogram, :func:`~..matching.projection.rotation_consistent`)."""
    local_keyframes: int = ranged(10, min=1)
    keyframe_ratio: float = ranged(0.75, gt=0, max=1)
    """New keyframe when inliers < this × the reference keyframe's tracked points (ORB-SLAM2 RGB-D)."""
    min_close_tracked: int = ranged(100, min=0)
    min_close_untracked: int = ranged(70, min=0)
    max_keyframe_interval: int = ranged(30, min=1)
    min_found_ratio: float = ranged(0.25, gt=0, max=1)
    min_observations: int = ranged(2, min=0)
    reloc_keyframes: int = ranged(6, min=1)
    """Relocalisation tries the keyframes with the most descriptor matches, this many at most."""
    reloc_ratio: float = ranged(0.75, gt=0, max=1)
    reloc_max_hamming: int = ranged(64, min=0, max=256)
    reloc_min_inliers: int = ranged(50, min=0)
    readout: float | None = ranged(None, min=0, lt=1)
    """Rolling-shutter readout of the colour camera, seconds from the top row to the bottom row:
    keypoints are moved to where they would be at the frame's stamp (:mod:`.rolling_shutter`).
    None = the camera's declared ``readout`` (``intrinsics.yaml``; TUM's fr1 / fr2 / fr3
    cameras 0.03), and no correction when it declares none; 0 = off."""
    reloc_recent_frames: int = ranged(30, min=0)
    """For this many frames after a relocalisation, tracking needs ``reloc_min_inliers`` inliers
    instead of ``min_inliers`` (ORB-SLAM2's ``TrackLocalMap``: 50 within ``mMaxFrames`` = the
    frame rate after ``mnLastRelocFrameId``); 0 = off."""
    reloc_local_radius: float = ranged(20.0, gt=0)
    """Window for local-map matching on the frame that relocalises and the next ones
    (``reloc_local_frames`` in all), px at level 0, 0.625× for near-frontal views, in place of
    ``local_radius``: a relocalised pose comes from PnP on descriptor matches and may sit further
    from the truth than a tracked one (ORB-SLAM2's ``SearchLocalPoints``: th 5 instead of the
    RGB-D 3 while ``mnId < mnLastRelocFrameId + 2``, ``RadiusByViewingCos`` 4 × 5)."""
    reloc_local_frames: int = ranged(2, min=0)
    """Frames that match the local map in ``reloc_local_radius``: the frame that relocalises and
    the ones after it, this many in all (ORB-SLAM2: 2, that frame and the next); 0 = off."""
    start_as_relocalisation: bool = False
    """True = the first keyframe counts as a relocalisation for ``reloc_recent_frames``,
    ``reloc_min_inliers`` and ``reloc_local_frames``, as ORB-SLAM2 (its ``mnLastRelocFrameId``
    starts at frame 0): the first frames, tracked on a map of one or two keyframes with a motion
    model not yet measured, need ``reloc_min_inliers`` inliers, and the second frame matches the
    local map in ``reloc_local_radius``. False (the default) = only a real relocalisation does:
    judged on the whole table, True removed the one bad repeat it was made for (``freiburg1_rpy``
    524-723 at every 5th frame: a third frame accepted 10.5° and 15 cm off with 47 inliers) but
    did not pass every rule fixed before the runs (docs/results/slam_table/README.md)."""

    def __post_init__(self) -> None:
        check_fields(self)

"""Per-frame tracking, as ORB-SLAM2's ``Tracking``: the :class:`~.tracker.Tracker` estimates each
frame's camera pose from its keypoints and the shared map (:mod:`..map`). One file per part: the
tracking loop (:mod:`.tracker`), its settings (:mod:`.config`), matching by projection
(:mod:`.projection`), PnP-RANSAC / PROSAC hypotheses and their refinement (:mod:`.sampling`),
relocalisation (:mod:`.relocalisation`), the keyframe rules (:mod:`.keyframes`), the pose-only
RGB-D optimisation (:mod:`.pose`) and the rolling-shutter correction (:mod:`.rolling_shutter`).
"""

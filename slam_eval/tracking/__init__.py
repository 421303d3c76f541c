"""Per-frame tracking, as ORB-SLAM2's ``Tracking``: the :class:`~.tracker.Tracker` estimates each
frame's camera pose from its keypoints and the shared map (:mod:`..map`). One file per part: the
tracking loop (:mod:`.tracker`), its settings (:mod:`.config`), relocalisation
(:mod:`.relocalisation`), the keyframe rules (:mod:`.keyframes`) and the rolling-shutter
correction (:mod:`.rolling_shutter`). Its matching and PnP sampling are :mod:`..matching`, its
pose-only RGB-D optimisation :mod:`..optim.pose`.
"""

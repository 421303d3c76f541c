"""Per-frame tracking: the :class:`~.tracker.Tracker` estimates each frame's camera pose from its
keypoints and the map (motion model, local map, relocalisation, keyframe decisions, as
ORB-SLAM2's ``Tracking``), with the pose-only RGB-D optimisation of :mod:`.pose`.
"""

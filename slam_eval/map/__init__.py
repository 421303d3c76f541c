"""The map state that tracking and the back end share, below both (as ORB-SLAM2's ``Map``,
``KeyFrame`` and ``MapPoint`` sit under its ``Tracking``, ``LocalMapping`` and ``LoopClosing``):
keyframes and map points (:mod:`.slam_map`) and the RGB-D observation model both optimise with
(:mod:`.observation`).
"""

"""The optimisations of the SLAM harness, as ORB-SLAM2's ``Optimizer``: the pose-only
optimisation of tracking (:mod:`.pose`). They read the shared RGB-D observation model
(:mod:`..map.observation`).
"""

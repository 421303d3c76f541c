"""The optimisations of the SLAM harness, as ORB-SLAM2's ``Optimizer``: the pose-only
optimisation of tracking (:mod:`.pose`) and the local bundle adjustment of local mapping and
loop closing (:mod:`.local_ba`). They read the shared RGB-D observation model
(:mod:`..map.observation`) and work on the shared map; neither imports tracking or the back end.
"""

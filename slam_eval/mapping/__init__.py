"""The back end over the shared map (:mod:`..map`): local bundle adjustment and keyframe culling
(:mod:`.local_mapping`) and loop closing with an SE(3) pose graph (:mod:`.loop_closing`), both on
GTSAM. The map products written at the end of a run (point cloud, OctoMap) are
:mod:`..products`.
"""

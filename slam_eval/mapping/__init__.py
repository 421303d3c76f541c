"""The back end over the shared map (:mod:`..map`): local bundle adjustment and keyframe culling
(:mod:`.local_mapping`), loop closing with an SE(3) pose graph (:mod:`.loop_closing`), both on
GTSAM, and the semantic maps of the static scene written at the end of a run: a point cloud
(:mod:`.semantic_map`, ``map.ply``) and an OctoMap (:mod:`.octomap`, ``octomap.ot``).
"""

"""What a run leaves of the static scene, built from the keyframes at their final poses and
written at the end: a semantic point cloud (:mod:`.semantic_map`, ``map.ply``) and a semantic
OctoMap (:mod:`.octomap`, ``octomap.ot``). Scoring reads them; neither tracking nor the back end
(:mod:`..mapping`) does.
"""

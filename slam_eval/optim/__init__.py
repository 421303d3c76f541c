"""The optimisations of the SLAM harness, as ORB-SLAM2's ``Optimizer``: the pose-only
optimisation of tracking (:mod:`.pose`), the local bundle adjustment of local mapping
(:mod:`.local_ba`) and the essential-graph optimisation of loop closing
(:mod:`.essential_graph`). They read the shared RGB-D observation model
(:mod:`..map.observation`) and work on the shared map; none imports tracking or the back end.
"""

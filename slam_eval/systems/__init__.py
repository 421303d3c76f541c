"""The SLAM systems ``uss-slam`` can run on a sequence: the harness, our ORB-SLAM2-style RGB-D
pipeline that chains segmenter, front end, filters, tracking and mapping
(:mod:`.harness`, ``system=harness``), and the real ORB-SLAM3 through its Python bindings
(:mod:`.orbslam3`, ``system=orbslam3``). Both read the same sequences and are scored and
reported the same way.
"""

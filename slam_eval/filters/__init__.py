"""Dynamic-keypoint filters, which drop the keypoints on moving objects before or after tracking:
the semantic mask of a segmenter's dynamic classes, ego-motion-compensated optical flow,
multi-view geometry, and the object rule that drops whole moving objects
(:mod:`.dynamic`, built by name from the ``filters=[...]`` config list).
"""

"""Dynamic-keypoint filters, which drop the keypoints on moving objects before or after tracking,
one file each: the semantic mask of a segmenter's dynamic classes (:mod:`.semantic`),
ego-motion-compensated optical flow (:mod:`.flow`), multi-view geometry (:mod:`.geometry`), and
the object rule that drops whole moving objects (:mod:`.object_rule`), over the shared types of
:mod:`.base`. They run in the order the ``filters=[...]`` config list names them, each built from
its ``slam.filter_params`` node by Hydra's ``instantiate`` (:mod:`.build`).
"""

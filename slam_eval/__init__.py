"""SLAM evaluation harness: run a SLAM system on a TUM RGB-D sequence with a segmenter and dynamic
filters, and score its trajectory against ground truth.

Never imports torch: it runs with NumPy, OpenCV, GTSAM and onnxruntime alone. One sub-package per
stage of a run, in the order data flows: :mod:`.sequence` (reading frames), :mod:`.segmenters`
(per-pixel classes), :mod:`.frontend` (ORB keypoints and matching), :mod:`.filters` (dropping
keypoints on moving objects), :mod:`.tracking` (per-frame pose), :mod:`.mapping` (map, local
bundle adjustment, loop closing, semantic maps), :mod:`.systems` (the harness pipeline that
chains them, and the real ORB-SLAM3), :mod:`.scoring` (ATE / RPE and the run report);
:mod:`.run` is the ``uss-slam`` entry point and :mod:`.config` its configuration.
"""

"""Where a SLAM run's per-pixel class labels come from: the segmenter interface, no segmenter and
the ground-truth ``labels/`` oracle (:mod:`.base`), the onnxruntime runtime of ``uss-export``
models (:mod:`.onnx`), and its optional dense-CRF refinement (:mod:`.crf`).
"""

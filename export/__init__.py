"""Checkpoint -> verified, self-describing ONNX segmenter (+ INT8), and the ``uss-export`` entry."""

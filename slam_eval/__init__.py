"""SLAM evaluation harness: TUM I/O, ONNX segmenter runtime, ORB odometry, dynamic filters, metrics.

Never imports torch: it runs with NumPy, OpenCV and onnxruntime alone.
"""

"""The torch-free shared core every other package may import: the project exception, the class
tables, TUM RGB-D file I/O, file hashing and the ONNX segmenter contract.

It imports nothing else of the project and needs only NumPy, OpenCV and PyYAML.
"""

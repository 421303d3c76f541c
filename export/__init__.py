"""Checkpoint -> verified, self-describing ONNX segmenter (+ INT8), and the ``uss-export`` entry.

- :mod:`~uss_slam.export.checkpoint`: a ``uss-train`` checkpoint -> its segmenter;
- :mod:`~uss_slam.export.wrapper`: the exported graph as a module (normalisation, argmax);
- :mod:`~uss_slam.export.onnx`: option checks, export with contract metadata, atomic writes;
- :mod:`~uss_slam.export.verify`: onnxruntime against PyTorch eager;
- :mod:`~uss_slam.export.quantize`: static INT8 calibrated on target frames;
- :mod:`~uss_slam.export.outputs`: file names and staged (atomic) writes;
- :mod:`~uss_slam.export.cli`: the Hydra app ``uss-export``.
"""

from uss_slam.export.checkpoint import LoadedCheckpoint, load_checkpoint, run_config_path
from uss_slam.export.onnx import (
    DEFAULT_OPSET,
    DEFAULT_TRACE_SIZE,
    MIN_OPSET,
    check_opset,
    export_checkpoint,
    export_segmenter,
    supported_opsets,
)
from uss_slam.export.outputs import ExportResult, sidecar
from uss_slam.export.quantize import (
    KEY_QUANTIZATION,
    CalibrationSet,
    add_int8,
    quantize_int8,
    read_calibration_frames,
)
from uss_slam.export.verify import (
    DEFAULT_VERIFY_SIZE,
    ExportVerificationError,
    make_session,
    verification_images,
    verify_model,
)
from uss_slam.export.wrapper import SegmenterExport

__all__ = [
    "DEFAULT_OPSET",
    "DEFAULT_TRACE_SIZE",
    "DEFAULT_VERIFY_SIZE",
    "KEY_QUANTIZATION",
    "MIN_OPSET",
    "CalibrationSet",
    "ExportResult",
    "ExportVerificationError",
    "LoadedCheckpoint",
    "SegmenterExport",
    "add_int8",
    "check_opset",
    "export_checkpoint",
    "export_segmenter",
    "load_checkpoint",
    "make_session",
    "quantize_int8",
    "read_calibration_frames",
    "run_config_path",
    "sidecar",
    "supported_opsets",
    "verification_images",
    "verify_model",
]

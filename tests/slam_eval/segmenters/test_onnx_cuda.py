"""The ONNX segmenter on onnxruntime's CUDA execution provider (``segmenter.providers=cuda`` or
``auto``). Marked ``gpu`` (skipped without CUDA, ``tests/conftest.py``) and skipped where this
onnxruntime build has no CUDA provider (the CPU-only ``onnxruntime`` package)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
from shared_helpers import colour_labels, colour_model, segmenter_props

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(
        "CUDAExecutionProvider" not in ort.get_available_providers(),
        reason="this onnxruntime build has no CUDAExecutionProvider (install onnxruntime-gpu)",
    ),
]


@pytest.mark.parametrize("providers", ["cuda", "auto"])
def test_segmenter_runs_on_the_cuda_provider(providers: str, tmp_path: Path) -> None:
    path = colour_model(tmp_path / "m.onnx", segmenter_props(CLASS_NAMES))
    seg = OnnxSegmenter(path, providers=providers)
    # the session really holds CUDA (onnxruntime falls back to CPU alone when CUDA fails to load)
    assert seg.providers == ["CUDAExecutionProvider", "CPUExecutionProvider"]
    rng = np.random.default_rng(0)
    for h, w in ((24, 32), (37, 53)):  # dynamic height / width, odd sizes
        rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        labels = seg.infer(rgb)
        assert labels.shape == (h, w) and labels.dtype == np.uint8
        np.testing.assert_array_equal(labels, colour_labels(rgb))  # the CPU provider's answer

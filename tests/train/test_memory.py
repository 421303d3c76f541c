"""The training memory estimate (train/memory.py): meta-device shapes, no memory used."""

from __future__ import annotations

import pytest
import torch
from shared_helpers import tiny_net

from uss_slam.train.memory import RUNTIME_BYTES, WORKER_BYTES, training_bytes


def test_training_estimate_grows_with_batch_and_crop() -> None:
    """The training estimate (meta-device shapes, no memory used): linear in the batch for the
    activations, larger for larger crops."""
    model = torch.nn.Module()
    model.segmenter = tiny_net()
    one, four = training_bytes(model, 1, (64, 64)), training_bytes(model, 4, (64, 64))
    fixed = sum(p.numel() for p in model.segmenter.parameters()) * 4 * 3 + RUNTIME_BYTES
    assert four - fixed == pytest.approx(4 * (one - fixed), rel=1e-6)
    assert training_bytes(model, 1, (128, 128)) > one
    assert training_bytes(model, 1, (64, 64), workers=2) == one + 2 * WORKER_BYTES

"""Fixtures of the export tests: synthetic data for a uss-train run, two torch threads."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import torch


@pytest.fixture(scope="session")
def uda_data(
    synthetic_voc: Callable[..., Path], synthetic_sequence: Callable[..., Path]
) -> dict[str, Path]:
    """Source VOC tree, a target training sequence and a labelled target validation sequence
    (the same synthetic data as the training tests)."""
    return {
        "voc": synthetic_voc(),
        "target": synthetic_sequence(),
        "val": synthetic_sequence(frames=6, size=(160, 120), seed=1),
    }


@pytest.fixture(autouse=True)
def _two_threads() -> Iterator[None]:
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(threads)

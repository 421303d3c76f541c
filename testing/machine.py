"""The machine a benchmark or study ran on, named the same way by every script that records it,
and the metadata its random-weight segmenters are exported with."""

from __future__ import annotations

from pathlib import Path

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.core.onnx_contract import SegmenterMetadata

CPUINFO = Path("/proc/cpuinfo")

SPEED_FLAGS = ("avx2", "avx512_bf16", "amx_bf16")
"""Instruction-set extensions that change this project's speed figures (bfloat16 matmuls, AMX)."""


def cpu_model(cpuinfo: Path = CPUINFO, flags: bool = False) -> str:
    """The CPU's model name from Linux's ``cpuinfo`` (``unknown CPU`` where there is none); with
    ``flags``, followed by the :data:`SPEED_FLAGS` it has, e.g. ``AMD EPYC (avx2, avx512_bf16)``."""
    try:
        lines = cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return "unknown CPU"
    names = [
        ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name") and ":" in ln
    ]
    name = names[0] if names else "unknown CPU"
    if not flags:
        return name
    found: set[str] = set()
    for line in lines:
        if line.startswith("flags") and ":" in line:
            found.update(line.split(":", 1)[1].split())
    have = [flag for flag in SPEED_FLAGS if flag in found]
    return f"{name} ({', '.join(have)})" if have else name


def benchmark_metadata(name: str) -> SegmenterMetadata:
    """The metadata a speed benchmark exports a random-weight segmenter with (no checkpoint:
    ``checkpoint_sha256`` ``random``): the project's classes, ``person`` dynamic, ImageNet
    normalisation, the main head, experiment ``benchmark-<name>``."""
    return SegmenterMetadata(
        class_names=CLASS_NAMES,
        dynamic_classes=("person",),
        mean=IMAGENET_MEAN,
        std=IMAGENET_STD,
        head="main",
        experiment=f"benchmark-{name}",
        checkpoint_sha256="random",
        version="benchmark",
    )

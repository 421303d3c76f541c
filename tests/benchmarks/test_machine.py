"""``uss_slam.testing.machine``: the CPU named the same way by every benchmark and study, with the
instruction-set extensions that change speed figures when asked; random-net export metadata."""

from __future__ import annotations

from pathlib import Path

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.testing.machine import benchmark_metadata, cpu_model

CPUINFO = """processor\t: 0
model name\t: AMD EPYC
flags\t\t: fpu sse2 avx2 avx512f avx512_bf16

processor\t: 1
model name\t: AMD EPYC
flags\t\t: fpu sse2 avx2 avx512f avx512_bf16
"""


def test_cpu_model_with_and_without_flags(tmp_path: Path) -> None:
    info = tmp_path / "cpuinfo"
    info.write_text(CPUINFO)
    assert cpu_model(info) == "AMD EPYC"
    assert cpu_model(info, flags=True) == "AMD EPYC (avx2, avx512_bf16)"
    info.write_text("processor\t: 0\nflags\t\t: fpu\n")
    assert cpu_model(info, flags=True) == "unknown CPU"
    assert cpu_model(tmp_path / "missing") == "unknown CPU"


def test_benchmark_metadata_round_trips() -> None:
    meta = benchmark_metadata("resnet101")
    assert meta.experiment == "benchmark-resnet101" and meta.class_names == CLASS_NAMES
    assert meta.dynamic_class_ids == (CLASS_NAMES.index("person"),)
    assert type(meta).from_props(meta.to_props()) == meta

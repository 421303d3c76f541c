"""``trainer.precision=auto``: the fastest precision for the CPU a run is on, said once.

bfloat16 autocast is fast on CPUs with bfloat16 instructions (AVX512-BF16 or AMX, through
oneDNN) and several times *slower* than float32 on CPUs without them, where oneDNN emulates it
(an AVX2-only machine: the demo model 6.4-7.2x slower than eager float32, BENCHMARKS "Training
speed options"). ``trainer=fast_cpu`` therefore asks for ``auto``, and the run resolves it
here: ``bf16-mixed`` where the CPU has the instructions, ``32-true`` elsewhere (its NHWC layout
and fused optimiser steps help on both). GPUs are not decided here: ``auto`` on a GPU trainer
means ``bf16-mixed`` when the device supports it, else ``16-mixed``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch

log = logging.getLogger(__name__)

BF16_FLAGS = ("avx512_bf16", "amx_bf16")
"""``/proc/cpuinfo`` flags of the instructions bfloat16 autocast needs to be fast on a CPU."""


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> set[str]:
    """The CPU's feature flags (Linux ``/proc/cpuinfo``; empty where there is none)."""
    try:
        text = cpuinfo.read_text(encoding="utf-8")
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags") and ":" in line:
            return set(line.split(":", 1)[1].split())
    return set()


def fast_cpu_bf16(flags: set[str] | None = None) -> bool:
    """True when this CPU runs bfloat16 autocast natively (one of :data:`BF16_FLAGS`)."""
    flags = cpu_flags() if flags is None else flags
    return any(flag in flags for flag in BF16_FLAGS)


def resolve_precision(precision: object, accelerator: object, flags: set[str] | None = None):
    """``precision`` unless it is ``"auto"``; then the choice for ``accelerator`` and why.

    Returns ``(precision, reason)``; ``reason`` is None when nothing was chosen here.
    """
    if str(precision) != "auto":
        return precision, None
    if str(accelerator) in ("gpu", "cuda") or (
        str(accelerator) == "auto" and torch.cuda.is_available()
    ):
        if torch.cuda.is_available() and torch.cuda.is_bf16_supported():
            return "bf16-mixed", "trainer.precision=auto: bf16-mixed (the GPU supports bfloat16)"
        return "16-mixed", "trainer.precision=auto: 16-mixed (no bfloat16 on this GPU)"
    flags = cpu_flags() if flags is None else flags
    found = sorted(flag for flag in BF16_FLAGS if flag in flags)
    if found:
        return "bf16-mixed", (
            f"trainer.precision=auto: bf16-mixed (this CPU has {', '.join(found)})"
        )
    return "32-true", (
        "trainer.precision=auto: 32-true (this CPU has neither AVX512-BF16 nor AMX, where "
        "bfloat16 autocast is several times slower than float32)"
    )

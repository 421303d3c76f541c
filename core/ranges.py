"""Value ranges a constructor declares in its annotations (``Annotated[int, Range(min=1)]``),
and the machine's bound on thread counts: torch-free and OmegaConf-free (floor 0), so that
``models/`` and ``datasets/`` declare their parameters' ranges without importing the schema
layer that reads them (:mod:`uss_slam.core.schema`)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from typing import Any


def machine_threads() -> int:
    """The CPUs this process may run on (its affinity mask; ``os.cpu_count`` elsewhere)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


THREADS_PER_CPU = 4
"""A thread count is bounded by the machine: at most this many threads per CPU it has. More
only take turns on the cores (and each one holds its own buffers): ``segmenter.threads=100000``
would spend minutes and gigabytes creating threads before the first frame."""
MAX_THREADS = THREADS_PER_CPU * machine_threads()
"""The largest thread count a setting takes on this machine (:data:`THREADS_PER_CPU` per CPU)."""


@dataclasses.dataclass(frozen=True)
class Range:
    """The same metadata as :func:`ranged`, for a constructor parameter built from a config
    (``max_iters: Annotated[int, Range(min=1)] = 250_000``): :func:`~.targets.target_schema`
    reads it from the annotation. Fields left None are not set."""

    min: float | None = None  # noqa: A003
    max: float | None = None  # noqa: A003
    gt: float | None = None
    lt: float | None = None
    choices: Sequence[Any] | None = None
    length: int | None = None
    text: bool | None = None
    nonempty: bool | None = None
    unique: bool | None = None

    @property
    def metadata(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) is not None}  # fmt: skip


THREADS = Range(min=1, max=MAX_THREADS)
"""The range of every thread count (:data:`MAX_THREADS`)."""
MAX_SEED = 2**32 - 1
"""The largest seed: numpy's (and so Lightning's ``seed_everything``); one rule for every seed
of every script (``uss-train seed``, ``uss-synth --seed``, ``uss-vocab build --seed``,
``uss-experiments``' seeds)."""
MAX_REPEATS = 1000
"""The most runs of one SLAM setting (``slam.repeats``, ``uss-experiments``' ``slam.repeats``
and ``slam.orbslam3.repeats``): a spread is estimated from a handful; a thousand runs of a 30 s
sequence take eight hours."""
MAX_FEATURES = 100_000
"""The most ORB features per frame any setting may ask for (``uss-vocab build --features``,
``slam.orb.n_features``, ``system.n_features``): ORB-SLAM's settings ask 1000-5000, and a
640x480 frame holds no more than a few ten thousand FAST corners; ten million would only
allocate."""


def check_stride(stride: int, frames: int, key: str, folder: object) -> None:
    """One rule for every "every N-th frame" option: a stride that is not below the frame count
    of a folder of several frames keeps only its first frame, never what was meant; refused
    naming ``key`` and ``folder``. (``uss-slam`` asks more of its own: ``sequence.stride``.)"""
    if stride > 1 and frames > 1 and stride >= frames:
        from uss_slam.core.errors import UssSlamError

        raise UssSlamError(
            f"{key} {stride}: {folder} has {frames} frames, so it would keep only the first; "
            f"expected a stride below {frames}"
        )

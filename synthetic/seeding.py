"""Named, reproducible random streams.

Every random decision draws from a generator derived from ``(seed, name, ...)`` with a stable
hash (CRC-32, not Python's salted ``hash``), so adding a new stream never shifts another one and
the same seed gives byte-identical output in every process.
"""

from __future__ import annotations

import zlib

import numpy as np


def stream(seed: int, name: str, *extra: int) -> np.random.Generator:
    """A generator for the stream ``name`` of ``seed`` (plus optional integer sub-keys)."""
    key = [int(seed) & 0xFFFFFFFF, zlib.crc32(name.encode()), *(int(e) & 0xFFFFFFFF for e in extra)]
    return np.random.default_rng(np.random.SeedSequence(key))

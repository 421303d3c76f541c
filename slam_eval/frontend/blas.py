"""One BLAS thread for the length of a SLAM run (:func:`one_blas_thread`).

NumPy's and SciPy's OpenBLAS start one thread per core and hand them every product above a small
size: in the harness that is the ORB orientation's ``(M, 961) @ (961, 2)`` product of each
pyramid level, a few hundred microseconds of work split over threads that then spin waiting for
the next job. On the two cores the harness shares between its main thread and its frame reading
(threads or the worker process of ``slam.prefetch_mode=process``), that spinning is CPU taken
from the other threads: 2.5–3 CPU ms per frame of ~40 in all, measured with
``benchmarks/slam_speed.py`` (BENCHMARKS.md, "SLAM harness speed"). The results do not change:
the orientation's sums are integers below 2^24, exact in any order, and the other products are
too small to be split.

Only OpenBLAS libraries already loaded in the process are touched (found in ``/proc/self/maps``
and opened with ``RTLD_NOLOAD``); elsewhere (no ``/proc``, another BLAS) this does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Callable, Iterator

_NAMES = (
    ("openblas_set_num_threads", "openblas_get_num_threads"),
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
    ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
)
"""(setter, getter) of the thread count in the OpenBLAS builds NumPy and SciPy ship (their
symbols carry a prefix or suffix) and in a plain OpenBLAS."""


def loaded_openblas(maps: str = "/proc/self/maps") -> list[tuple[Callable, Callable]]:
    """``(set_num_threads, get_num_threads)`` of every OpenBLAS library this process has loaded
    (none where ``maps`` cannot be read)."""
    try:
        with open(maps, encoding="utf-8", errors="replace") as lines:
            paths = sorted({line.split()[-1] for line in lines if "openblas" in line.lower()})
    except OSError:
        return []
    found = []
    for path in paths:
        if not os.path.isfile(path) or ".so" not in os.path.basename(path):
            continue
        try:
            lib = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)
        except OSError:
            continue
        for set_name, get_name in _NAMES:
            setter, getter = getattr(lib, set_name, None), getattr(lib, get_name, None)
            if setter is not None and getter is not None:
                setter.argtypes, setter.restype = [ctypes.c_int], None
                getter.argtypes, getter.restype = [], ctypes.c_int
                found.append((setter, getter))
                break
    return found


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Every loaded OpenBLAS limited to one thread inside the block; the counts they had are
    restored after it."""
    libraries = loaded_openblas()
    before = [(setter, getter()) for setter, getter in libraries]
    for setter, _ in before:
        setter(1)
    try:
        yield
    finally:
        for setter, count in before:
            setter(count)

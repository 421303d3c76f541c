"""One thread in the libraries' own pools for the length of a SLAM run (:func:`one_thread_pools`).

NumPy's and SciPy's OpenBLAS and OpenCV start one thread per core and hand them every product
(OpenBLAS) or image operation (OpenCV: resizes, colour conversions, blurs, dilations) above a
small size; after each job those threads spin waiting for the next one. In the harness the jobs
are small (the ORB orientation's ``(M, 961) @ (961, 2)`` product of each pyramid level, a
640x480 dilation) and the run's own threads already keep the two cores busy (the main thread,
and the frame reading in threads or in the worker process of ``slam.prefetch_mode=process``),
so the spinning is CPU taken from them: OpenBLAS's 2.5–3 CPU ms per frame of ~40 in all
(``benchmarks/slam_speed.py``, BENCHMARKS.md "SLAM harness speed"), OpenCV's ~0.6 ms per frame
in each process (``perf``: its pool thread in ``sched_yield``). The results do not change: the
orientation's sums are integers below 2^24, exact in any order, OpenBLAS splits a product's rows
and columns (never its sums) over threads, and OpenCV's parallel loops split image rows.

Only OpenBLAS libraries already loaded in the process are touched (found in ``/proc/self/maps``
and opened with ``RTLD_NOLOAD``); elsewhere (no ``/proc``, another BLAS) only OpenCV's pool is.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Callable, Iterator

import cv2

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
def one_thread_pools() -> Iterator[None]:
    """Every loaded OpenBLAS and OpenCV limited to one thread inside the block; the counts they
    had are restored after it."""
    libraries = loaded_openblas()
    before = [(setter, getter()) for setter, getter in libraries]
    opencv = cv2.getNumThreads()
    for setter, _ in before:
        setter(1)
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(opencv)
        for setter, count in before:
            setter(count)


_KEPT: list[contextlib.AbstractContextManager] = []
"""The block :func:`one_thread_pools_for_life` entered (kept so that it is never closed)."""


def one_thread_pools_for_life() -> None:
    """:func:`one_thread_pools` entered for the rest of this process's life (the frame reader
    process's). The block is kept: a generator's block that nothing refers to after its
    ``__enter__`` is closed by the garbage collector at once, which runs its ``finally`` and
    gives the pools their threads back (in the worker process that cost an OpenCV pool thread
    spinning in ``sched_yield``, ~1 CPU ms a frame)."""
    if not _KEPT:
        block = one_thread_pools()
        block.__enter__()
        _KEPT.append(block)

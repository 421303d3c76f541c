"""One thread in OpenBLAS's and OpenCV's pools during a SLAM run
(:mod:`uss_slam.slam_eval.frontend.pools`)."""

from __future__ import annotations

import gc
import sys

import cv2
import numpy as np
import pytest

from uss_slam.slam_eval.frontend import pools
from uss_slam.slam_eval.frontend.pools import (
    loaded_openblas,
    one_thread_pools,
    one_thread_pools_for_life,
)

needs_openblas = pytest.mark.skipif(
    not sys.platform.startswith("linux") or not loaded_openblas(),
    reason="no OpenBLAS found in /proc/self/maps",
)


@needs_openblas
def test_one_thread_inside_and_the_counts_restored_after() -> None:
    libraries = loaded_openblas()
    before = [get() for _, get in libraries]
    opencv = cv2.getNumThreads()
    with one_thread_pools():
        assert [get() for _, get in libraries] == [1] * len(libraries)
        assert cv2.getNumThreads() == 1
        a = np.arange(600 * 961, dtype=np.float32).reshape(600, 961) % 7
        assert (a @ np.ones((961, 2), np.float32)).shape == (600, 2)  # BLAS still works
    assert [get() for _, get in libraries] == before
    assert cv2.getNumThreads() == opencv


@needs_openblas
def test_restored_after_an_error() -> None:
    before = [get() for _, get in loaded_openblas()]
    with pytest.raises(RuntimeError), one_thread_pools():
        raise RuntimeError("in the run")
    assert [get() for _, get in loaded_openblas()] == before


def test_for_life_outlives_the_collector() -> None:
    """The frame reader process's pools stay at one thread after the block's object is gone
    (a dropped generator's block would be closed and the threads given back)."""
    opencv = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        one_thread_pools_for_life()
        gc.collect()
        assert cv2.getNumThreads() == 1
        assert [get() for _, get in loaded_openblas()] == [1] * len(loaded_openblas())
        one_thread_pools_for_life()  # a second call enters nothing more
        assert len(pools._KEPT) == 1
    finally:
        for block in pools._KEPT:
            block.__exit__(None, None, None)
        pools._KEPT.clear()
        cv2.setNumThreads(opencv)


def test_no_maps_file_finds_nothing(tmp_path) -> None:
    assert loaded_openblas(str(tmp_path / "missing")) == []


def test_a_maps_line_of_another_library_is_skipped(tmp_path) -> None:
    maps = tmp_path / "maps"
    maps.write_text(
        "7f00-7f01 r-xp 0 08:01 1 /nowhere/libopenblas.so.0\n"  # not a file: skipped
        "7f01-7f02 r-xp 0 08:01 2 /usr/lib/libc.so.6\n"
    )
    assert loaded_openblas(str(maps)) == []

"""core.processes.pool_ending_with_parent: a forked pool worker never destroys what it inherited
from the parent (an object left for the garbage collector, such as an onnxruntime session whose
lock has no owner thread in the worker, hung the worker for ever when the worker's collector
ran its destructor)."""

from __future__ import annotations

import gc
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from uss_slam.core.processes import pool_ending_with_parent


class _Cycle:
    """A reference cycle whose destructor writes the pid of the process that ran it."""

    def __init__(self, record: Path) -> None:
        self.record = record
        self.me = self

    def __del__(self) -> None:
        with open(self.record, "a") as out:
            out.write(f"{os.getpid()}\n")


def _collect() -> int:
    """In a worker: a full collection, as any allocation-heavy task would trigger."""
    gc.collect()
    return os.getpid()


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork start method only")
def test_a_pool_worker_never_destroys_the_parents_garbage(tmp_path: Path) -> None:
    record = tmp_path / "destroyed_by"
    gc.disable()  # keep the cycle uncollected until the pool is made, as a busy parent would
    try:
        _Cycle(record)
        kwargs = pool_ending_with_parent()
    finally:
        gc.enable()
    with ProcessPoolExecutor(max_workers=2, **kwargs) as pool:
        workers = {pool.submit(_collect).result() for _ in range(4)}
    destroyed = record.read_text().split() if record.exists() else []
    assert destroyed == [str(os.getpid())]  # by the parent, before the workers forked
    assert not workers & {int(pid) for pid in destroyed}


def test_a_pool_worker_freezes_what_it_inherited() -> None:
    with ProcessPoolExecutor(max_workers=1, **pool_ending_with_parent()) as pool:
        assert pool.submit(gc.get_freeze_count).result() > 0

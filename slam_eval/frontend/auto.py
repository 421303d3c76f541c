"""``slam.prefetch_mode=auto``: the worker process (:mod:`.process`) where the run has a second
core to itself, else the threads (:func:`resolve_mode`)."""

from __future__ import annotations

import multiprocessing
import os
import statistics
import time

FREE_CORES = 1.5
"""``auto`` takes the worker process when at least this many cores are idle as the run starts
(the main thread's, and most of another for the worker's reading and extraction)."""
SAMPLE_S = 0.03
"""How long each of ``auto``'s looks at the CPUs' idle time (``/proc/stat``) lasts, seconds:
3 ticks of the kernel's 10 ms CPU-time counters per core, so that one tick counted busy or
idle by chance moves the estimate by a third of a core on two CPUs, not half of it."""
SAMPLES = 5
"""Consecutive looks of :data:`SAMPLE_S` whose median ``auto`` takes (0.15 s in all before a
run): a moment of work (a process starting or ending, a previous run's threads winding down)
is busy in one or two of them, other jobs' steady load in most."""


def resolve_mode(mode: str, sample: bool = True) -> str:
    """``thread`` or ``process`` for a ``slam.prefetch_mode`` of ``mode``.

    ``auto`` is the worker process where the run has a second core to itself, and the threads
    where it is one of several parallel jobs: ``thread`` on one usable CPU, inside a process
    pool's worker (joblib's workers, which ``uss-experiments`` runs its jobs in through Hydra's
    joblib launcher, or a ``multiprocessing`` pool) and, with ``sample``, when fewer than
    :data:`FREE_CORES` cores were idle in the median of :data:`SAMPLES` looks of
    :data:`SAMPLE_S` seconds (other jobs take them; :func:`free_cores`); else ``process``. On
    two idle cores the worker process is the faster; when other jobs take the cores it costs
    more CPU per frame than the threads and is slower (BENCHMARKS.md, "SLAM harness speed").
    Either way the trajectory is the same."""
    if mode != "auto":
        return mode
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # no affinity API (macOS, Windows)
        usable = os.cpu_count() or 1
    if usable < 2 or multiprocessing.parent_process() is not None:
        return "thread"
    free = free_cores() if sample else None
    return "thread" if free is not None and min(free, usable) < FREE_CORES else "process"


def free_cores(
    seconds: float = SAMPLE_S, stat: str = "/proc/stat", samples: int = SAMPLES
) -> float | None:
    """Cores of the machine that other processes leave idle: the median over ``samples``
    consecutive looks of ``seconds`` each of all CPUs less the busy time of the ``cpu`` line of
    ``stat`` (everything but idle and I/O wait), less this process's own CPU time meanwhile
    (its pools' threads may still spin after its last run); None where ``stat`` cannot be read
    (not Linux). The median: a burst of work that is over within two looks (a process starting
    or ending) leaves the answer as on idle cores; a load that lasts (other jobs) does not."""
    before = _cpu_times(stat)
    frees: list[float] = []
    for _ in range(samples):
        if before is None:
            return None
        wall, own = time.perf_counter(), time.process_time()
        time.sleep(seconds)
        after = _cpu_times(stat)
        wall, own = time.perf_counter() - wall, time.process_time() - own
        free = None if after is None else _free(before, after, wall, own)
        if free is not None:
            frees.append(free)
        before = after
    return statistics.median(frees) if frees else None


def _free(
    before: tuple[list[int], int], after: tuple[list[int], int], wall: float, own: float
) -> float | None:
    """Idle cores between two readings of ``stat`` ``wall`` seconds apart, this process's own
    ``own`` CPU seconds counted as idle; None when no time was counted."""
    spent = [b - a for a, b in zip(before[0], after[0], strict=True)]
    total = sum(spent)
    if total <= 0 or wall <= 0:
        return None
    cpus = before[1]
    others = cpus * (total - spent[3] - spent[4]) / total - own / wall
    return cpus - max(0.0, others)


def _cpu_times(stat: str) -> tuple[list[int], int] | None:
    """The ``cpu`` line's first eight times (user, nice, system, idle, iowait, irq, softirq,
    steal) and the number of CPUs, or None."""
    try:
        with open(stat, encoding="ascii") as lines:
            rows = [line.split() for line in lines if line.startswith("cpu")]
        times = [int(v) for v in rows[0][1:9]]
    except (OSError, ValueError, IndexError):
        return None
    if rows[0][0] != "cpu" or len(times) < 8:
        return None
    return times, max(1, len(rows) - 1)

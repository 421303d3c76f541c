"""Child processes that end with the process that started them.

A console script killed with ``kill -9`` gets no chance to stop its children: without help they
keep running, and keep writing into outputs that a rerun then writes too. On Linux each child
asks the kernel for a signal when its parent ends (``prctl(PR_SET_PDEATHSIG)``): SIGTERM, which
ends a Python process at once. Elsewhere nothing is done (the output locks of
:func:`uss_slam.core.files.output_lock` still keep a rerun out while a survivor writes).

    proc = subprocess.Popen(command, preexec_fn=ends_with_parent())
    pool = ProcessPoolExecutor(max_workers=2, **pool_ending_with_parent())

A console script interrupted by Ctrl-C or SIGTERM (:func:`uss_slam.core.cli.signals_as_interrupts`)
ends the workers of such a pool at once (:func:`end_pool_workers`): a pool would otherwise wait
for their tasks before the script's cleanup runs. The workers ignore Ctrl-C themselves (the
terminal sends it to them too), so that none of them prints a traceback.

A launcher may put processes of its own between a driver and its jobs (submitit's local
executor does), which the signal does not reach through: the driver names itself in the
jobs' environment (:func:`watched_by_children`) and each job ends when that process has ended
(:func:`end_with_watched`, a thread that looks every half second).
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import multiprocessing
import os
import signal
import sys
import threading
import time
import weakref
from collections.abc import Callable
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any

from uss_slam.core.launch import TERMINATING

PR_SET_PDEATHSIG = 1
"""``prctl`` option: the signal this process gets when its parent ends (linux/prctl.h)."""


def _load_prctl() -> Callable[..., int] | None:
    """libc's ``prctl``, resolved once in the parent (a ``preexec_fn`` must not load libraries:
    it runs between fork and exec)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


_prctl = _load_prctl()


def die_with_parent(parent: int | None = None, sig: int = signal.SIGTERM) -> bool:
    """Make the calling process get ``sig`` when its parent ends; True where this is possible
    (Linux). ``parent``: the pid the parent had; if it has ended already (before the call),
    the calling process gets ``sig`` now.

    The kernel's notion of the parent is the *thread* that forked: start children from a
    thread that lives as long as they should (the main thread).
    """
    if _prctl is None or _prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        return False
    if parent is not None and os.getppid() != parent:
        os.kill(os.getpid(), sig)  # the parent ended before the call: nobody will signal it
    return True


def ends_with_parent(sig: int = signal.SIGTERM) -> Callable[[], None] | None:
    """A ``preexec_fn`` for :class:`subprocess.Popen` (run in the child between fork and exec)
    that makes the child get ``sig`` when this process ends; None where that is not possible."""
    if _prctl is None:
        return None
    parent = os.getpid()

    def preexec() -> None:
        die_with_parent(parent, sig)

    return preexec


def pool_ending_with_parent(sig: int = signal.SIGTERM) -> dict[str, Any]:
    """``initializer`` / ``initargs`` / ``mp_context`` for
    :class:`concurrent.futures.ProcessPoolExecutor`: each worker gets ``sig`` when this process
    ends (create the pool in the main thread), ignores Ctrl-C, and is ended by
    :func:`end_pool_workers` when this process is interrupted.

    Garbage is collected here, before the workers fork: an unreachable object left for the
    collector (an onnxruntime session, a thread pool) would otherwise be destroyed in a worker,
    whose copy of its lock has no owner thread there, and hang it; each worker also freezes what
    it inherited (:func:`gc.freeze`), so that its collector never destroys the parent's objects."""
    gc.collect()
    return {
        "initializer": _start_pool_worker,
        "initargs": (os.getpid(), sig),
        "mp_context": _TrackedContext(),
    }


def _start_pool_worker(parent: int, sig: int) -> None:
    """A pool worker's initializer: SIGTERM ends it at once (so do the parent's other stopping
    signals, :data:`~uss_slam.core.launch.TERMINATING`, but Ctrl-\\), Ctrl-C is left to the
    parent (which ends it: :func:`end_pool_workers`), and the parent's end ends it too. A forked worker
    would otherwise keep the parent's Python handlers and print a traceback on either signal.
    What a forked worker inherited is frozen out of its garbage collector (see
    :func:`pool_ending_with_parent`)."""
    gc.freeze()
    for other in TERMINATING:  # (SIGHUP, SIGUSR1...: the parent's handler; one ignored stays)
        if callable(signal.getsignal(other)):
            signal.signal(other, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGQUIT, signal.SIG_IGN)  # Ctrl-\ too reaches the terminal's group
    die_with_parent(parent, sig)


_pool_workers: weakref.WeakSet[Any] = weakref.WeakSet()
"""The worker processes of the pools made with :func:`pool_ending_with_parent`."""


class _TrackedContext:
    """This process's default multiprocessing context, recording each process it creates in
    :data:`_pool_workers`."""

    def __init__(self) -> None:
        self._base = multiprocessing.get_context()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._base, name)

    def Process(self, *args: Any, **kwargs: Any) -> Any:  # noqa: N802 (multiprocessing's name)
        process = self._base.Process(*args, **kwargs)
        _pool_workers.add(process)
        return process


def end_pool_workers(grace: float = 2.0) -> int:
    """SIGTERM to every running worker of a pool made with :func:`pool_ending_with_parent`,
    SIGKILL to those still running ``grace`` seconds later; returns how many were signalled.

    The processes are not reaped here (their pool does that); whether one still runs is read
    from its sentinel."""
    running: dict[Any, int] = {}
    for process in list(_pool_workers):
        try:
            sentinel, pid = process.sentinel, process.pid
        except (ValueError, AttributeError):  # not started, or closed
            continue
        if pid is None or wait([sentinel], timeout=0):
            continue
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:
            continue
        running[sentinel] = pid
    signalled = len(running)
    deadline = time.monotonic() + grace
    while running and time.monotonic() < deadline:
        for sentinel in wait(list(running), timeout=max(0.0, deadline - time.monotonic())):
            running.pop(sentinel, None)
    for pid in running.values():
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return signalled


WATCH_ENV = "USS_SLAM_END_WITH"
"""Environment variable naming the process (``pid:start``) whose end ends a job."""
KILL_AFTER = 2.0
"""Seconds a watched job has after its signal before it is killed."""
_watching: set[str] = set()
_watching_guard = threading.Lock()


def _start_time(pid: int) -> str | None:
    """The kernel's start time of ``pid`` (field 22 of ``/proc/<pid>/stat``), which tells a
    reused pid from the process; None when ``pid`` has ended (or is a zombie)."""
    try:
        fields = (
            Path(f"/proc/{pid}/stat")
            .read_text(encoding="utf-8", errors="replace")
            .rsplit(")", 1)[1]
            .split()
        )
    except OSError:
        return None
    return None if fields[0] in ("Z", "X") else fields[19]


def watched_by_children() -> dict[str, str]:
    """The environment for the children of this process whose jobs must end with it (empty
    where ``/proc`` is not there)."""
    start = _start_time(os.getpid())
    return {} if start is None else {WATCH_ENV: f"{os.getpid()}:{start}"}


def end_with_watched(sig: int = signal.SIGTERM, every: float = 0.5) -> bool:
    """When :data:`WATCH_ENV` names a process, get ``sig`` once it has ended (a daemon thread
    checks every ``every`` seconds), and SIGKILL :data:`KILL_AFTER` seconds later if still
    running; True when a watch is on."""
    value = os.environ.get(WATCH_ENV, "")
    pid_text, _, start = value.partition(":")
    if not pid_text.isdigit() or not start:
        return False
    pid = int(pid_text)
    with _watching_guard:
        if value in _watching:  # a reused worker process: one watch for all its jobs
            return True
        _watching.add(value)

    def watch() -> None:
        while _start_time(pid) == start:
            time.sleep(every)
        os.kill(os.getpid(), sig)
        # a launcher may catch the signal (submitit's jobs take SIGTERM for a preemption)
        time.sleep(KILL_AFTER)
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="end-with-watched", daemon=True).start()
    return True

"""Child processes that end with the process that started them.

A console script killed with ``kill -9`` gets no chance to stop its children: without help they
keep running, and keep writing into outputs that a rerun then writes too. On Linux each child
asks the kernel for a signal when its parent ends (``prctl(PR_SET_PDEATHSIG)``): SIGTERM, which
ends a Python process at once. Elsewhere nothing is done (the output locks of
:func:`uss_slam.core.files.output_lock` still keep a rerun out while a survivor writes).

    proc = subprocess.Popen(command, preexec_fn=ends_with_parent())
    pool = ProcessPoolExecutor(max_workers=2, **pool_ending_with_parent())
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

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
    """``initializer`` / ``initargs`` for :class:`concurrent.futures.ProcessPoolExecutor`: each
    worker gets ``sig`` when this process ends (create the pool in the main thread)."""
    return {"initializer": die_with_parent, "initargs": (os.getpid(), sig)}

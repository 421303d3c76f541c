"""Standard output that cannot be written (redirected to a full disk, ``/dev/full``, a device
that fails, or closed before the script started): never a traceback, and never a script that
stops half-way because a progress note could not be printed.

:func:`guard` (installed by ``core/launch.py`` before the script's module is imported) wraps
``sys.stdout`` so that a write that fails keeps its error (:func:`lost`) instead of raising;
a script's *product* on stdout (``uss-traj``'s numbers, ``uss-vocab info``, a dry run's plan)
is printed by :func:`uss_slam.core.cli.print_output`, which then makes it the error line
(exit code 1); anything else printed there is lost with one warning at the end
(:func:`report_lost`). A closed pipe (``| head -1``: its reader is gone) is kept the same way:
a product's is print_output's rule (exit code 1 without a word), the rest's the one warning,
never a ``BrokenPipeError`` traceback after the work.

Imports nothing outside the standard library (``core/launch.py`` uses it before the imports).
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Any, TextIO


class _GuardedStream:
    """``sys.stdout`` whose failing writes and flushes are kept, not raised (a closed pipe's
    ``BrokenPipeError`` too: :func:`uss_slam.core.cli.print_output` reads it from :func:`lost`)."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        self.lost: OSError | None = None

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as error:
            self.lost = self.lost or error
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as error:
            self.lost = self.lost or error

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def guard() -> None:
    """Wrap ``sys.stdout`` (once; nothing when it is closed: ``None``). A character the
    stream's encoding cannot hold (a non-ASCII path under ``PYTHONIOENCODING=ascii`` or a
    Latin-1 terminal) is written as its escape (``\\xe9``) on stdout and stderr alike, not a
    ``UnicodeEncodeError`` traceback after the work was done."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError, OSError):  # None, or a test's
            stream.reconfigure(errors="backslashreplace")  # type: ignore[union-attr]
    if sys.stdout is not None and not isinstance(sys.stdout, _GuardedStream):
        sys.stdout = _GuardedStream(sys.stdout)  # type: ignore[assignment]
    if sys.stderr is None:
        _stderr_to_null()


def _stderr_to_null() -> None:
    """Stderr closed (``2>&-``): Python's ``sys.stderr`` is None, and ``print(..., file=None)``
    writes to stdout, so the error and warning lines would land in the script's product
    (``uss-traj --json > r.json``). They go nowhere instead (the exit code still tells), and
    file descriptor 2 is ``/dev/null`` for the libraries and processes that write there."""
    null = os.open(os.devnull, os.O_WRONLY)
    if null != 2:
        os.dup2(null, 2)
        os.close(null)
    sys.stderr = open(2, "w", encoding="utf-8", errors="backslashreplace", closefd=False)  # noqa: SIM115


def lost(clear: bool = False) -> OSError | None:
    """The first error of a write to stdout that failed since the guard was installed (or the
    last ``clear``), else None."""
    stream = sys.stdout
    error = getattr(stream, "lost", None) if isinstance(stream, _GuardedStream) else None
    if clear and isinstance(stream, _GuardedStream):
        stream.lost = None
    return error


def closed() -> bool:
    """Whether the script started with stdout closed (Python's ``sys.stdout`` is then None)."""
    return sys.stdout is None


def report_lost(prog: str) -> None:
    """At the end of a script: one warning when something it printed on stdout was lost, and
    stdout pointed at ``/dev/null`` so that the interpreter's last flush raises nothing (what
    is still buffered is flushed first: a closed pipe shows only then)."""
    with contextlib.suppress(Exception):
        if isinstance(sys.stdout, _GuardedStream):
            sys.stdout.flush()
    error = lost(clear=True)
    if error is None:
        return
    if isinstance(error, BrokenPipeError):
        print(f"{prog}: warning: stdout: its reader closed the pipe (| head?); the rest of what "
              "the script printed there is lost (its files are complete)", file=sys.stderr)  # fmt: skip
    else:
        why = error.strerror or type(error).__name__
        print(f"{prog}: warning: stdout: cannot write to it ({why}); what the script printed "
              "there is lost (its files are complete)", file=sys.stderr)  # fmt: skip
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # not a file (a test harness's)
        pass

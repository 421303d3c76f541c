"""Progress bars that fit where they go: every progress bar of the project is made here.

In a terminal a bar redraws in place as tqdm's always does. Written to a file or a CI log (the
stream is not a TTY) a redraw would be one more line per update (thousands in a demo log), so
the bar writes plain lines instead: one when it starts, at most one every
:data:`LOG_INTERVAL` seconds while it runs, and one with the totals when it ends::

    for frame in progress_bar(frames, desc="frames", unit="frame"):
        ...
    with progress_bar(total=n, desc="parts") as bar:
        bar.update()
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from typing import IO, Any

from tqdm import tqdm

LOG_INTERVAL = 30.0
"""Seconds between two lines of a bar written to a file or log."""


def is_terminal(stream: IO[str] | None) -> bool:
    """True when ``stream`` (None: stderr, tqdm's default) is an interactive terminal."""
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


class LineProgress(tqdm):
    """A tqdm bar that writes whole lines, for a file or a log: the first state, then at most one
    line every ``interval`` seconds, then the final state (with the overall rate) when closed.
    Iterating, ``update``, ``set_postfix`` and the context manager work as tqdm's."""

    def __init__(self, *args: Any, interval: float = LOG_INTERVAL, **kwargs: Any) -> None:
        self.interval = float(interval)
        self._line_at: float | None = None
        # tqdm's own rate limit keeps the cost of an update low; the lines are limited below
        kwargs.setdefault("mininterval", min(self.interval, 1.0))
        super().__init__(*args, **kwargs)

    def display(self, msg: str | None = None, pos: int | None = None) -> bool:
        """Write the bar's state as one line, unless one was written less than ``interval``
        seconds ago; an empty ``msg`` (tqdm clearing the bar) writes nothing."""
        if msg == "":
            return False
        now = time.monotonic()
        if self._line_at is not None and now - self._line_at < self.interval:
            return False
        self._write_line(msg)
        return True

    def _write_line(self, msg: str | None = None) -> None:
        self._line_at = time.monotonic()
        self.fp.write((self.__str__() if msg is None else msg).strip() + "\n")
        self.fp.flush()

    def close(self) -> None:
        """Write the final line (when the bar is left, as tqdm's ``leave``), then close. A bar
        whose ``__init__`` was interrupted (Ctrl-C) closes quietly, as tqdm's own does."""
        if getattr(self, "disable", True):
            return
        if self.leave is not False and hasattr(self, "last_print_t"):
            self._ema_dt = lambda: None  # the overall rate, as tqdm's own final display
            self._write_line()
        self.leave = False  # tqdm's close would add a newline after its final display
        super().close()


def progress_bar(
    iterable: Iterable[Any] | None = None,
    *,
    file: IO[str] | None = None,
    interval: float = LOG_INTERVAL,
    **kwargs: Any,
) -> tqdm:
    """A progress bar over ``iterable`` (or updated by hand, with ``total=``): tqdm's in a
    terminal, a :class:`LineProgress` when ``file`` (None: stderr) is not one. ``kwargs`` are
    tqdm's (``desc``, ``unit``, ``total``, ``disable``, ...)."""
    if is_terminal(file):
        return tqdm(iterable, file=file, **kwargs)
    return LineProgress(
        iterable, file=sys.stderr if file is None else file, interval=interval, **kwargs
    )

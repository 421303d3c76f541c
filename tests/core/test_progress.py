"""Progress bars: redrawn in a terminal, whole lines (first, at most one per interval, last) in a
file or a log; the Lightning bar of uss-train the same way."""

from __future__ import annotations

import gc
import io
import sys

import pytest
from tqdm import tqdm

from uss_slam.core import progress as progress_module
from uss_slam.core.cli import exit_on_user_error
from uss_slam.core.errors import UssSlamError
from uss_slam.core.progress import LineProgress, is_terminal, progress_bar


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_gets_tqdms_bar_and_a_file_gets_lines() -> None:
    assert is_terminal(_Terminal()) and not is_terminal(io.StringIO())
    bar = progress_bar(range(3), file=_Terminal())
    assert type(bar) is tqdm
    bar.close()
    assert isinstance(progress_bar(range(3), file=io.StringIO()), LineProgress)


def test_a_log_gets_a_first_and_a_last_line_not_one_per_update() -> None:
    log = io.StringIO()
    with progress_bar(total=2000, desc="frames", unit="frame", file=log, mininterval=0) as bar:
        for _ in range(2000):
            bar.update()
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue() and log.getvalue().endswith("\n")
    assert len(lines) == 2, lines
    assert lines[0].startswith("frames:   0%") and "0/2000" in lines[0]
    assert lines[1].startswith("frames: 100%") and "2000/2000" in lines[1]


def test_a_line_every_interval(monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: now[0])
    log = io.StringIO()
    bar = progress_bar(total=10, desc="parts", file=log, interval=30.0)
    for seconds in (10.0, 10.0, 15.0, 5.0):  # at 110, 120, 135, 140 s
        now[0] += seconds
        bar.update()
        bar.refresh()  # a redraw request, as Lightning's bar makes one per batch
    bar.close()
    lines = log.getvalue().splitlines()
    # start (100 s), the first redraw 30 s after it (135 s), the end
    assert [line.split("|")[0].strip() for line in lines] == [
        "parts:   0%",
        "parts:  30%",
        "parts:  40%",
    ]


def test_a_disabled_or_unfinished_bar() -> None:
    log = io.StringIO()
    for _ in progress_bar(range(5), file=log, disable=True):
        pass
    assert log.getvalue() == ""
    log = io.StringIO()
    bar = progress_bar(total=4, desc="x", file=log, leave=False)
    bar.update(2)
    bar.close()
    assert len(log.getvalue().splitlines()) == 1  # not left behind: only its first line


def test_a_bar_whose_creation_was_interrupted_closes_quietly(monkeypatch) -> None:
    """Ctrl-C inside tqdm's ``__init__`` (before it set ``disable``): the half-made bar's
    ``__del__`` -> ``close`` must not raise (an "Exception ignored" report after
    ``<prog>: interrupted``)."""

    def interrupted(self, *args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tqdm, "__init__", interrupted)
    log = io.StringIO()
    with pytest.raises(KeyboardInterrupt):
        progress_bar(total=3, file=log)
    half = LineProgress.__new__(LineProgress)
    half.close()  # what __del__ calls
    assert log.getvalue() == ""


def _parts_then(error: BaseException, log: io.StringIO) -> None:
    bar = progress_bar(total=9, desc="parts", file=log)  # left open, as an interrupt leaves it
    bar.update()
    raise error


@pytest.mark.parametrize(
    "error, last",
    [(KeyboardInterrupt(), "prog: interrupted"), (UssSlamError("bad"), "prog: error: bad")],
)
def test_the_scripts_last_line_is_last_no_bar_drawn_after_it(
    monkeypatch: pytest.MonkeyPatch, error: BaseException, last: str
) -> None:
    """A bar the interrupt (or error) left open is closed before the line, not when the
    traceback holding it is freed, which drew it again below the line (uss-demo's parts)."""
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    with pytest.raises(SystemExit), exit_on_user_error("prog"):
        _parts_then(error, log)
    gc.collect()
    lines = log.getvalue().splitlines()
    assert lines[-1] == last, lines
    assert lines[-2].startswith("parts:  11%") and "1/9" in lines[-2], lines

"""Ctrl-C that Python drops (raised inside a weakref callback or ``__del__``) is kept and
raised later, so a console script never finishes as if no one had pressed it."""

from __future__ import annotations

import sys

import pytest
from shared_helpers import drop_in_weakref_callback

from uss_slam.core.cli import (
    INTERRUPTED,
    exit_on_user_error,
    interrupts_deferred,
    interrupts_kept,
    raise_dropped_interrupt,
)


def test_a_dropped_interrupt_is_silent_and_raised_at_the_next_check(capsys) -> None:
    with interrupts_kept():
        drop_in_weakref_callback(KeyboardInterrupt())
        assert capsys.readouterr().err == ""  # not "Exception ignored in ..."
        with pytest.raises(KeyboardInterrupt):
            raise_dropped_interrupt()
        raise_dropped_interrupt()  # raised once


def _reported(monkeypatch) -> list[BaseException]:
    """What reaches the unraisable hook that was there before (Python's, or pytest's)."""
    seen: list[BaseException] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))
    return seen


def test_other_dropped_errors_are_still_reported(monkeypatch) -> None:
    reported = _reported(monkeypatch)
    with interrupts_kept():
        drop_in_weakref_callback(ValueError("boom"))
        raise_dropped_interrupt()  # not an interrupt: nothing to raise
    assert [str(e) for e in reported] == ["boom"]


def test_outside_the_block_python_reports_it_as_before(monkeypatch) -> None:
    reported = _reported(monkeypatch)
    hook = sys.unraisablehook
    with interrupts_kept():
        assert sys.unraisablehook is not hook
    assert sys.unraisablehook is hook
    drop_in_weakref_callback(KeyboardInterrupt())
    assert [type(e) for e in reported] == [KeyboardInterrupt]
    raise_dropped_interrupt()  # nothing kept outside the block


def test_a_deferred_step_does_not_start_after_a_dropped_interrupt() -> None:
    started = []
    with interrupts_kept(), pytest.raises(KeyboardInterrupt):
        drop_in_weakref_callback(KeyboardInterrupt())
        with interrupts_deferred():
            started.append(True)
    assert started == []


def test_a_console_script_exits_130_when_the_body_ends_after_a_dropped_interrupt(capsys):
    with pytest.raises(SystemExit) as stop, exit_on_user_error("uss-x"):
        drop_in_weakref_callback(KeyboardInterrupt())
    assert stop.value.code == INTERRUPTED
    assert capsys.readouterr().err.splitlines() == ["uss-x: interrupted"]


def test_a_console_script_without_interrupt_ends_normally(monkeypatch) -> None:
    reported = _reported(monkeypatch)
    with exit_on_user_error("uss-x"):
        drop_in_weakref_callback(ValueError("elsewhere"))
    assert [str(e) for e in reported] == ["elsewhere"]


def test_sigterm_is_an_interrupt_named_in_the_line(capsys) -> None:
    import os
    import signal

    from uss_slam.core.cli import TERMINATED

    with pytest.raises(SystemExit) as stop, exit_on_user_error("uss-x"):
        os.kill(os.getpid(), signal.SIGTERM)
    assert stop.value.code == TERMINATED
    assert capsys.readouterr().err.splitlines() == ["uss-x: interrupted (SIGTERM)"]
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # restored


def test_sighup_is_an_interrupt_named_in_the_line(capsys) -> None:
    """The terminal closed (an SSH connection lost): SIGTERM's contract, exit code 129."""
    import os
    import signal

    before = signal.signal(signal.SIGHUP, signal.SIG_DFL)  # (a test run under nohup ignores it)
    try:
        with pytest.raises(SystemExit) as stop, exit_on_user_error("uss-x"):
            os.kill(os.getpid(), signal.SIGHUP)
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_DFL  # restored
    finally:
        signal.signal(signal.SIGHUP, before)
    assert stop.value.code == 129
    assert capsys.readouterr().err.splitlines() == ["uss-x: interrupted (SIGHUP)"]


@pytest.mark.parametrize("name", ["SIGQUIT", "SIGXCPU", "SIGUSR1", "SIGUSR2", "SIGALRM"])
def test_sigquit_sigxcpu_and_unassigned_signals_are_interrupts_named_in_the_line(
    name: str, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-\\ (SIGQUIT) and a CPU-time limit reached (SIGXCPU: ``ulimit -St``, a batch
    system's), whose default is to die at once with a core dump, and the signals with no
    meaning of their own (``kill -USR1``, an alarm), whose default is to die at once: SIGTERM's
    contract, the same cleanup, exit code 128 + the signal's number."""
    monkeypatch.delenv("SLURM_JOB_ID", raising=False)
    import os
    import signal

    sig = signal.Signals[name]
    before = signal.signal(sig, signal.SIG_DFL)
    try:
        with pytest.raises(SystemExit) as stop, exit_on_user_error("uss-x"):
            os.kill(os.getpid(), sig)
        assert signal.getsignal(sig) is signal.SIG_DFL  # restored
    finally:
        signal.signal(sig, before)
    assert stop.value.code == 128 + sig
    assert capsys.readouterr().err.splitlines() == [f"uss-x: interrupted ({name})"]


@pytest.mark.parametrize("name", ["SIGUSR1", "SIGUSR2", "SIGALRM"])
def test_an_unassigned_signal_another_handler_takes_stays_its(name: str) -> None:
    """A launcher's handler (submitit's jobs take SIGUSR2, Lightning SIGUSR1, for a requeue)
    is neither replaced nor deferred."""
    import os
    import signal

    from uss_slam.core.cli import signals_as_interrupts

    sig = signal.Signals[name]
    got: list[int] = []
    before = signal.signal(sig, lambda signum, frame: got.append(signum))
    try:
        with signals_as_interrupts(), interrupts_deferred():
            os.kill(os.getpid(), sig)
            assert got == [sig]  # at once, by its own handler
    finally:
        signal.signal(sig, before)


@pytest.mark.parametrize("name", ["SIGUSR1", "SIGUSR2"])
def test_a_slurm_jobs_warning_signal_is_left_to_the_launcher(
    name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """In a SLURM job, SIGUSR1 and SIGUSR2 are ``sbatch --signal``'s warnings before the time
    limit, which Lightning and submitit take for a requeue once they start: left as they are."""
    import signal

    from uss_slam.core.cli import signals_as_interrupts

    monkeypatch.setenv("SLURM_JOB_ID", "17")
    sig = signal.Signals[name]
    before = signal.signal(sig, signal.SIG_DFL)
    try:
        with signals_as_interrupts():
            assert signal.getsignal(sig) is signal.SIG_DFL
    finally:
        signal.signal(sig, before)


def test_a_deferred_step_finishes_before_sigterm_takes_effect() -> None:
    import os
    import signal

    from uss_slam.core.cli import Terminated, signals_as_interrupts

    done = []
    with signals_as_interrupts(), pytest.raises(Terminated), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGTERM)
        done.append(True)
    assert done == [True]


@pytest.mark.parametrize("sig_name", ["SIGINT", "SIGTERM"])
def test_an_error_that_follows_an_interrupt_is_reported_as_the_interrupt(sig_name, capsys):
    """A process pool whose workers the interrupt ended can report itself broken before the
    interrupt reaches the body (the interrupt caught where Python drops it): the one line of
    the interrupt, no traceback."""
    import contextlib
    import os
    import signal
    from concurrent.futures.process import BrokenProcessPool

    sig = signal.Signals[sig_name]
    with pytest.raises(SystemExit) as stop, exit_on_user_error("uss-x"):
        with contextlib.suppress(KeyboardInterrupt):  # swallowed where it was raised
            os.kill(os.getpid(), sig)
        raise BrokenProcessPool("A process in the process pool was terminated abruptly")
    assert stop.value.code == 128 + sig
    named = "" if sig == signal.SIGINT else " (SIGTERM)"
    assert capsys.readouterr().err.splitlines() == [f"uss-x: interrupted{named}"]


def test_an_error_without_an_interrupt_still_propagates() -> None:
    with pytest.raises(RuntimeError, match="real"), exit_on_user_error("uss-x"):
        raise RuntimeError("real failure")


def test_a_second_interrupt_during_the_cleanup_lets_it_finish(monkeypatch) -> None:
    """Ctrl-C twice (or a terminal's Ctrl-C reaching every process of its group): the cleanup
    the first one started runs to its end (it was cut short: a leaked shared-memory block, a
    staging folder left); one long after it (:data:`CLEANUP_GRACE_S`) still stops a cleanup
    that hangs."""
    import os
    import signal

    from uss_slam.core import cli
    from uss_slam.core.cli import signals_as_interrupts

    cleaned = []
    with pytest.raises(KeyboardInterrupt), signals_as_interrupts():
        try:
            os.kill(os.getpid(), signal.SIGINT)
        finally:
            os.kill(os.getpid(), signal.SIGINT)  # during the cleanup: absorbed
            cleaned.append(True)
    assert cleaned == [True]
    monkeypatch.setattr(cli, "CLEANUP_GRACE_S", 0.0)
    with pytest.raises(KeyboardInterrupt), signals_as_interrupts():
        try:
            os.kill(os.getpid(), signal.SIGINT)
        finally:
            with pytest.raises(KeyboardInterrupt):  # past the grace period: raised again
                os.kill(os.getpid(), signal.SIGINT)

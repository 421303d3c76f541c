"""What every console script does with a user error: one line on stderr, exit code 1 (2 for an
output another process is writing, :class:`~uss_slam.core.errors.OutputInUseError`).

SIGTERM (``kill``, ``timeout``, a scheduler's preemption, a container stop) is handled as Ctrl-C
(:func:`signals_as_interrupts`): the same cleanup runs, and the one line names the signal
(``<prog>: interrupted (SIGTERM)``, exit code :data:`TERMINATED`).

Unexpected internal errors keep their traceback; only the project's own errors (and the config
errors an entry point names) count as the user's, and so does a full disk (``ENOSPC`` /
``EDQUOT`` from any library: ``no space left on device while writing <path>``). Hydra wraps
errors raised while instantiating an object, so the whole ``__cause__`` / ``__context__`` chain
is searched.

Hydra apps (``uss-train``, ``uss-slam``) also let the jobs of a multirun fail independently: a
user error in one job is printed and recorded, the other jobs run, and the failed ones are
listed at the end with exit code 1. Hydra and OmegaConf are imported only inside the functions
that need them (this module stays importable without them).
"""

from __future__ import annotations

import functools
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TypeVar

from uss_slam.core import job_records
from uss_slam.core.errors import NoSpaceError, UssSlamError
from uss_slam.core.files import no_space_errno
from uss_slam.core.hydra_lines import (  # noqa: F401 (their home before)
    adding_refused_over_any_key,
    as_typed,
    hydra_error_line,
    hydra_switch_line,
    hydra_switch_texts,
    list_items_quoted_argv,
    output_folder_line,
    override_parse_line,
    repeated_override_line,
    typed_overrides,
)
from uss_slam.core.launch import TERMINATING, close_open_bars, taken
from uss_slam.core.run_folders import (
    RefusedRunFolder,
    RunFolderCheck,
    forget_run_folders,
    release_run_folders,
    started_folder_again,
    undo_hydra_records,
)

__all__ = ["RefusedRunFolder", "RunFolderCheck"]  # (configs name core.cli.RunFolderCheck)

T = TypeVar("T")

INTERRUPTED = 130
"""Exit code after Ctrl-C (128 + SIGINT, as shells report a process stopped by it)."""
TERMINATED = 143
"""Exit code after SIGTERM (128 + SIGTERM)."""


INTERRUPTING = (signal.SIGINT, *TERMINATING)
"""The signals a console script handles as Ctrl-C: SIGTERM (``kill``) and SIGHUP (the terminal
closed, an SSH connection lost) raise :class:`Terminated`, the same cleanup runs, the line
names the signal and the exit code is 128 + its number (143, 129)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as an interrupt: every ``except KeyboardInterrupt`` and ``finally`` that
    cleans up after Ctrl-C (staging folders, temporary files, locks, child processes) runs."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_received: int | None = None
"""The signal that interrupted the console script (SIGINT or SIGTERM; None: none, or a
``KeyboardInterrupt`` not sent as a signal), kept once the handlers are restored."""
_handlers_depth = 0
"""How many :func:`signals_as_interrupts` blocks are active (the outermost one resets
:data:`_received`)."""


_first_at: float | None = None
"""When (``time.monotonic``) the interrupt of :data:`_received` came."""
CLEANUP_GRACE_S = 5.0
"""Seconds after an interrupt during which a further Ctrl-C, SIGTERM or SIGHUP is absorbed
(a user presses Ctrl-C twice; a terminal's Ctrl-C reaches every process of its group): the
cleanup the first one started (removing a staging folder, freeing shared memory, joining
workers) is not cut short, which left its files or a leaked shared-memory block. A later one
raises again: a cleanup that hangs can still be stopped."""


def _interrupt_handler(signum: int, frame: object) -> None:
    """SIGINT / SIGTERM in a console script: end the pool workers this process started (they
    ignore Ctrl-C, so that none prints a traceback, and a pool would otherwise wait for their
    tasks), then raise the interrupt in the main thread. A second one within
    :data:`CLEANUP_GRACE_S` of the first does nothing."""
    global _received, _first_at
    now = time.monotonic()
    if _received is not None and _first_at is not None and now - _first_at < CLEANUP_GRACE_S:
        return  # the first one's cleanup is running: let it finish
    _received, _first_at = signum, now
    from uss_slam.core.processes import end_pool_workers

    end_pool_workers()
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


@contextmanager
def signals_as_interrupts() -> Iterator[None]:
    """During the block, SIGTERM and SIGHUP are handled as Ctrl-C: they raise :class:`Terminated` (a
    ``KeyboardInterrupt``) in the main thread; Ctrl-C raises ``KeyboardInterrupt`` as before.
    Either first ends the pool workers of :func:`uss_slam.core.processes.pool_ending_with_parent`.

    A signal Python does not handle (ignored, as a shell's background job ignores Ctrl-C) stays
    as it is; outside the main thread the block runs as it is. The handlers in place before
    are restored when the block ends; :func:`interrupt_signal` still names the signal then.
    """
    global _handlers_depth, _received, _first_at
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _handlers_depth == 0:
        _received = None
        _first_at = None
    previous = {sig: signal.getsignal(sig) for sig in INTERRUPTING}
    for sig, handler in previous.items():
        if not taken(sig, handler) or (sig == signal.SIGINT and not callable(handler)):
            continue  # ignored by whoever started us, a launcher's, or handled outside Python
        signal.signal(sig, _interrupt_handler)
    _handlers_depth += 1
    try:
        yield
    finally:
        _handlers_depth -= 1
        for sig, handler in previous.items():
            if handler is not None:
                signal.signal(sig, handler)


def interruptible(main: Callable[..., T]) -> Callable[..., T]:
    """Decorator of a console script's ``main`` that handles its own ``KeyboardInterrupt``
    (with :func:`report_interrupt`): the body runs in :func:`signals_as_interrupts`."""

    @functools.wraps(main)
    def wrapped(*args: Any, **kwargs: Any) -> T:
        with signals_as_interrupts():
            return main(*args, **kwargs)

    return wrapped


def interrupt_signal(error: BaseException | None = None) -> int:
    """The signal that interrupted the console script: SIGTERM when a :class:`Terminated` is
    ``error`` or was raised by :func:`signals_as_interrupts`' handler (a library may re-raise
    it as a plain ``KeyboardInterrupt``), else SIGINT."""
    if isinstance(getattr(error, "signum", None), int):  # (launch's, before the script's)
        return error.signum  # type: ignore[union-attr]
    return _received if _received is not None else signal.SIGINT


def report_interrupt(prog: str, error: BaseException | None = None, note: str = "") -> int:
    """Print the one line of an interrupted console script and return its exit code:
    ``<prog>: interrupted`` and :data:`INTERRUPTED` after Ctrl-C, ``<prog>: interrupted
    (SIGTERM)`` and :data:`TERMINATED` after SIGTERM; ``note`` is appended after ``; ``."""
    signum = interrupt_signal(error)
    named = "" if signum == signal.SIGINT else f" ({signal.Signals(signum).name})"
    close_open_bars()  # drawn now, not again after the line
    print(f"{prog}: interrupted{named}" + (f"; {note}" if note else ""), file=sys.stderr)
    return 128 + int(signum)


CLOSED_PIPE = 1
"""Exit code when stdout was closed before the output was written (``... | head -c0``): the
reader did not get it. Nothing is printed on stderr; the convention of Python's documentation
(``BrokenPipeError``)."""


def check_stdout_open() -> None:
    """A :class:`UssSlamError` when stdout is closed (``>&-``): a script whose product is on
    stdout calls it before any work, so that the error is its one line."""
    from uss_slam.core import stdout

    if stdout.closed():
        raise UssSlamError("stdout is closed (>&-): the output cannot be written")


def print_output(text: str) -> int:
    """Print ``text`` on stdout and return the exit code: 0, or :data:`CLOSED_PIPE` when the
    reader closed the pipe; then stdout is pointed at ``/dev/null``, so that the flush at exit
    raises nothing either (no traceback, no ``Exception ignored`` line). Stdout closed or
    failing otherwise (a full disk, ``/dev/full``: :mod:`uss_slam.core.stdout`) is a
    :class:`UssSlamError`: the output was not delivered."""
    from uss_slam.core import stdout

    check_stdout_open()
    try:
        print(text, flush=True)
        error = stdout.lost(clear=True)
        if isinstance(error, BrokenPipeError):  # (kept by the guard)
            raise error
        if error is not None:
            why = error.strerror or type(error).__name__
            raise UssSlamError(f"stdout: cannot write the output ({why})")
    except BrokenPipeError:
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        except (OSError, ValueError):  # stdout is not a file (replaced by a test harness)
            pass
        return CLOSED_PIPE
    return 0


_program: str | None = None
"""The console script running now (set by :func:`exit_on_user_error` / :func:`program`)."""


@contextmanager
def program(prog: str) -> Iterator[None]:
    """Name the console script for :func:`warning` during the block."""
    global _program
    previous, _program = _program, prog
    try:
        yield
    finally:
        _program = previous


def warning(message: str) -> None:
    """One line ``<prog>: warning: <message>`` on stderr (the README's form of a warning);
    outside a console script, a logged warning."""
    if _program is None:
        logging.getLogger(__name__).warning("%s", message)
    else:
        print(f"{_program}: warning: {message}", file=sys.stderr)


_dropped_interrupts: list[object] | None = None
"""Ctrl-C that Python dropped while :func:`interrupts_kept` is active (None outside it)."""


@contextmanager
def interrupts_kept() -> Iterator[None]:
    """Keep a Ctrl-C that Python would drop, and raise it at the next :func:`raise_dropped_interrupt`.

    A ``KeyboardInterrupt`` raised while Python runs a weakref callback or a ``__del__`` (the
    import system's module locks use one) cannot propagate: Python prints ``Exception ignored
    in: ...`` and goes on, so the program would finish as if no one had pressed Ctrl-C. During
    the block such an interrupt prints nothing and is recorded instead; other unraisable
    exceptions are reported as before. Console scripts run their body in it
    (:func:`exit_on_user_error`), and a run checks before it moves its outputs into place
    (:func:`interrupts_deferred`)."""
    global _dropped_interrupts
    previous_hook, previous_list = sys.unraisablehook, _dropped_interrupts
    dropped: list[object] = []

    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            dropped.append(unraisable.object)
        else:
            previous_hook(unraisable)

    sys.unraisablehook, _dropped_interrupts = hook, dropped
    try:
        yield
    finally:
        sys.unraisablehook, _dropped_interrupts = previous_hook, previous_list


def raise_dropped_interrupt() -> None:
    """Raise ``KeyboardInterrupt`` if Python dropped one during :func:`interrupts_kept`."""
    if _dropped_interrupts:
        _dropped_interrupts.clear()
        raise KeyboardInterrupt


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Ctrl-C (SIGINT) or SIGTERM during the block takes effect when it ends: for a short step
    that must not stop half-way (moving a finished run's files into place). A Ctrl-C that
    Python dropped earlier (:func:`interrupts_kept`) is raised before the block starts. Outside
    the main thread, or for a signal that is not Python's to handle, the block runs as it is."""
    raise_dropped_interrupt()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in INTERRUPTING}
    # ignored, default (SIGTERM ends the process at once) or handled outside Python: left alone
    ours = {sig: h for sig, h in previous.items() if h is _interrupt_handler or taken(sig, h)}
    deferred = {sig: handler for sig, handler in ours.items() if callable(handler)}
    caught: list[int] = []
    for sig in deferred:
        signal.signal(sig, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for sig, handler in deferred.items():
            signal.signal(sig, handler)
    if caught:
        # Python's default SIGINT handler or signals_as_interrupts' raise the interrupt
        deferred[caught[0]](caught[0], None)


def user_error(
    error: BaseException | None, kinds: tuple[type[BaseException], ...] = ()
) -> BaseException | None:
    """The first error in ``error``'s cause chain that is a user error, else None."""
    accepted = (UssSlamError, *kinds)
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, accepted):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def no_space_error(error: BaseException) -> NoSpaceError | None:
    """A :class:`NoSpaceError` for an ``OSError`` of a full disk in ``error``'s cause chain that
    no writer of the project named (it names the file when the ``OSError`` has one)."""
    code = no_space_errno(error)
    if code is None:
        return None
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno == code:
            return NoSpaceError(current.filename, code)
        current = current.__cause__ or current.__context__
    return NoSpaceError(None, code)


def exit_code(error: BaseException) -> int:
    """The exit code of a console script stopped by the user error ``error``: its
    ``exit_code`` (:class:`UssSlamError`'s: 1; an output in use: 2), else 1."""
    code = getattr(error, "exit_code", 1)
    return code if isinstance(code, int) and not isinstance(code, bool) else 1


def error_line(prog: str, error: BaseException) -> str:
    """``"<prog>: error: <first line of the message>"``."""
    text = str(error).strip() or type(error).__name__
    return f"{prog}: error: {text.splitlines()[0]}"


@dataclass(frozen=True)
class FailedJob:
    """A multirun job stopped by a user error."""

    num: int
    overrides: tuple[str, ...]
    line: str


@dataclass
class JobReport:
    """The jobs of one Hydra app call (one run, or every job of a multirun)."""

    prog: str
    started: int = 0
    """Jobs whose task function started (0: Hydra failed before running any)."""
    overrides: list[tuple[str, ...]] = field(default_factory=list)
    """The task overrides of each multirun job started."""
    failures: list[FailedJob] = field(default_factory=list)

    def summary(self) -> str:
        """``<prog>: k of n jobs failed:`` and one line per failed job: its number, the
        overrides that tell it from the other jobs as typed (:func:`as_typed`), its error line."""
        common = set.intersection(*map(set, self.overrides)) if len(self.overrides) > 1 else set()
        lines = [f"{self.prog}: {len(self.failures)} of {self.started} jobs failed:"]
        for failed in self.failures:
            own = " ".join(as_typed(o) for o in failed.overrides if o not in common)
            lines.append(f"  #{failed.num} {own or '(no overrides)'}: {failed.line}")
        return "\n".join(lines)


class JobFailed(Exception):
    """A Hydra multirun job stopped by a user error, already printed and recorded: Hydra marks
    the job failed and runs the others (raised instead of exiting the process)."""


_report: JobReport | None = None
"""The report of the Hydra app call in progress (set by :func:`report_failed_jobs`)."""


def _multirun_job() -> tuple[int, tuple[str, ...]] | None:
    """``(job number, task overrides)`` inside a job of a Hydra multirun, else None (Hydra is
    imported only if the process already did)."""
    if "hydra" not in sys.modules:
        return None
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if not HydraConfig.initialized():
        return None
    config = HydraConfig.get()
    if config.mode != RunMode.MULTIRUN:
        return None
    return int(config.job.num), tuple(typed_overrides(config))


@contextmanager
def exit_on_user_error(prog: str, kinds: tuple[type[BaseException], ...] = ()) -> Iterator[None]:
    """Run the body; a user error anywhere in the cause chain becomes one line and exit code 1
    (:func:`exit_code`: 2 for an output in use); so does a full disk (:func:`no_space_error`).

    ``kinds`` adds exception types the entry point treats as user errors (Hydra apps pass
    OmegaConf's config errors). Ctrl-C is one line ``<prog>: interrupted`` and exit code
    :data:`INTERRUPTED` (a multirun stops as a whole), also when Python dropped it
    (:func:`interrupts_kept`): then at the next check, at the latest when the body ends; any
    error raised after the interrupt arrived is reported as the interrupt.
    SIGTERM is handled as Ctrl-C (:func:`signals_as_interrupts`): ``<prog>: interrupted
    (SIGTERM)`` and exit code :data:`TERMINATED`.
    Anything else propagates with its traceback.

    Inside a job of a Hydra multirun whose console script runs the app under
    :func:`report_failed_jobs`, the line is printed and recorded and :class:`JobFailed` is
    raised instead of exiting: the other jobs still run, the failed ones are listed at the end.
    The Hydra task catches it and returns (``None``), so that Hydra counts the job as done and
    adds no report of its own.
    """
    report = _report
    worker_job = None  # a multirun job in a launcher's own process (joblib): its record
    if report is not None:
        report.started += 1
        job = _multirun_job()
        if job is not None:
            report.overrides.append(job[1])
    else:
        worker_job = _multirun_job()
        if worker_job is not None:
            job_records.record(*worker_job)
    try:
        with program(prog), signals_as_interrupts(), interrupts_kept():
            yield
            raise_dropped_interrupt()
    except SystemExit:
        raise
    except KeyboardInterrupt as interrupt:
        # Ctrl-C or SIGTERM: a stop asked for, not a failure to explain with a traceback.
        sys.exit(report_interrupt(prog, interrupt))
    except BaseException as error:
        if _received is not None:
            # The error followed a stop asked for (a process pool whose workers the interrupt
            # ended reports itself broken before the interrupt reaches the body): the stop is
            # what to report.
            sys.exit(report_interrupt(prog, error))
        missing = _missing_package(prog, error)
        if missing is not None:  # a required package, first imported here (maybe by Hydra)
            print(missing, file=sys.stderr)
            sys.exit(1)
        cause = user_error(error, kinds) or no_space_error(error)
        if cause is None:
            from uss_slam.core.launch import MEMORY_LINE, out_of_memory

            if not out_of_memory(error):
                raise
            # here, not after the app: a Hydra app would print its own report of the job first
            cause = UssSlamError(MEMORY_LINE)
        line = error_line(prog, cause)
        close_open_bars()
        print(line, file=sys.stderr)
        if worker_job is not None:  # the console script lists it; the other jobs go on
            job_records.record(*worker_job, line=line)
            raise JobFailed(line) from None
        job = _multirun_job() if report is not None else None
        if report is None or job is None:
            sys.exit(exit_code(cause))
        report.failures.append(FailedJob(job[0], job[1], line))
        raise JobFailed(line) from None


def _missing_package(prog: str, error: BaseException) -> str | None:
    """The launcher's line for a required package that is not installed, found anywhere in
    ``error``'s chain (Hydra's ``instantiate`` wraps the import's error in its own), else
    None."""
    from uss_slam.core.launch import missing_package_line

    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, ModuleNotFoundError):
            line = missing_package_line(prog, current)
            if line is not None:
                return line
        current = current.__cause__ or current.__context__
    return None


def hydra_task(prog: str, task: Callable[[Any], T], cfg: Any) -> T | None:
    """``task(cfg)`` as the body of a ``@hydra.main`` app: in :func:`exit_on_user_error`, with
    OmegaConf's config errors counted as the user's. None when it was a multirun job that failed
    with a user error (printed and recorded; the other jobs go on)."""
    from omegaconf.errors import OmegaConfBaseException

    from uss_slam.core.schema.compose import check_interpolations

    try:
        with exit_on_user_error(prog, (OmegaConfBaseException,)):
            started_folder_again(prog)  # hydra.job.chdir=true: relative paths as without it
            check_interpolations(cfg)  # ${oc.env:X} unset: one line naming its key
            return task(cfg)
    except JobFailed:
        return None


@contextmanager
def report_failed_jobs(prog: str) -> Iterator[JobReport]:
    """Around the call of a ``@hydra.main`` app in its console script: a multirun job that
    fails with a user error (in :func:`exit_on_user_error`) does not stop the sweep; at the end
    the failed jobs are listed on stderr and the exit code is 1.

    Hydra must raise its errors rather than print its own report (``HYDRA_FULL_ERROR=1``, as
    :func:`run_hydra_app` sets): its sweeper re-raises the first failed job after running them
    all. Yields the :class:`JobReport` (jobs started, failures).
    """
    global _report
    report, previous = JobReport(prog), _report
    _report = report
    try:
        yield report
    except JobFailed:
        pass
    finally:
        _report = previous
        for job in job_records.collect():  # jobs run in a launcher's own processes
            report.started += 1
            overrides = tuple(str(o) for o in job["overrides"])  # type: ignore[attr-defined]
            report.overrides.append(overrides)
            if job["line"] is not None:
                report.failures.append(FailedJob(int(job["num"]), overrides, str(job["line"])))  # type: ignore[call-overload]
        if report.failures:
            print(report.summary(), file=sys.stderr)
    if report.failures:
        sys.exit(1)


def run_hydra_app(prog: str, app: Callable[[], object]) -> None:
    """The console script of a ``@hydra.main`` app: ``app()`` with every user error as one
    line on stderr and exit code 1 — config composition errors, an output folder Hydra cannot
    create, the app's own errors (:func:`exit_on_user_error` inside it) — and a multirun's
    failed jobs listed at the end (:func:`report_failed_jobs`). Internal errors keep their
    traceback. Ctrl-C and SIGTERM (:func:`signals_as_interrupts`) while Hydra composes the
    config are the same one line as in the app."""
    previous = os.environ.get("HYDRA_FULL_ERROR")
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra raises instead of printing its own report
    report = JobReport(prog)
    sys.argv[1:] = list_items_quoted_argv(sys.argv[1:])
    repeated = repeated_override_line(sys.argv[1:])
    if repeated is not None:
        print(f"{prog}: error: {repeated}", file=sys.stderr)
        sys.exit(1)
    done = False  # else Hydra's record of the run is undone: a refused run writes nothing
    try:
        with (program(prog), signals_as_interrupts(), report_failed_jobs(prog) as report,
              hydra_switch_texts(prog, sys.argv[1:]), adding_refused_over_any_key()):  # fmt: skip
            app()
        done = True
    except SystemExit as stop:
        done = stop.code in (0, None)
        raise
    except KeyboardInterrupt as interrupt:  # before the app's own handling (composition)
        sys.exit(report_interrupt(prog, interrupt))
    except RefusedRunFolder as refused:
        print(error_line(prog, refused.error), file=sys.stderr)
        sys.exit(exit_code(refused.error))
    except Exception as error:
        line = hydra_error_line(error)
        if line is None and isinstance(error, OSError) and not report.started:
            line = output_folder_line(error)  # Hydra could not create its output folder
        if line is None and not report.started:  # a switch of Hydra's own it cannot follow
            line = hydra_switch_line(error, sys.argv[1:])
        if line is None:
            raise
        print(f"{prog}: error: {line}", file=sys.stderr)
        sys.exit(1)
    finally:
        forget_run_folders() if done else undo_hydra_records()
        release_run_folders()
        if previous is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = previous

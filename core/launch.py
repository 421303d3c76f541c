"""The console scripts' entry points (``[project.scripts]`` in pyproject.toml): each imports
its script's module and calls its ``main``, so that what the machine lacks is one line too:

- a required package that is not installed (the script's module cannot be imported):
  ``<prog>: error: the required package <dist> (import <name>) is not installed ...`` with the
  command that installs it, as the optional packages' errors give theirs (exit code 1);
- memory (``MemoryError``: the machine's, or a limit such as ``ulimit -v``):
  ``<prog>: error: out of memory ...`` (exit code 1) after the script's own cleanup ran (its
  temporary and partial outputs removed as after any error);
- an address-space limit (``ulimit -v``) too small to load the libraries at all
  (:data:`ADDRESS_SPACE_FLOOR`): the same ``out of memory`` line, before the imports (between
  about 300 and 460 MB OpenCV's import killed the process with SIGSEGV);
- Ctrl-C or SIGTERM while the script's libraries are still being imported (the first seconds
  of a run, longer on a busy machine) or before the script's own handling starts:
  ``<prog>: interrupted`` (exit code 130; SIGTERM: ``<prog>: interrupted (SIGTERM)``, 143), as
  later in the run, never an import's traceback nor the kernel's default.

Imports nothing outside the standard library before the script's module.
"""

from __future__ import annotations

import atexit
import codecs
import contextlib
import importlib
import os
import resource
import signal
import sys
from collections.abc import Callable
from importlib import metadata

from uss_slam.core import stdout
from uss_slam.core.library_warnings import quiet_known_warnings

SCRIPTS = {
    "uss-synth": "uss_slam.synthetic.cli",
    "uss-traj": "uss_slam.slam_eval.scoring.traj_cli",
    "uss-slam": "uss_slam.slam_eval.run",
    "uss-vocab": "uss_slam.slam_eval.systems.orbslam3.vocab_cli",
    "uss-train": "uss_slam.train.train",
    "uss-export": "uss_slam.export.cli",
    "uss-demo": "uss_slam.pipelines.demo",
    "uss-eval": "uss_slam.pipelines.evaluate",
    "uss-experiments": "uss_slam.pipelines.experiments.cli",
}
"""Console script -> the module whose ``main`` it runs."""

REQUIRED = {
    "numpy": "numpy", "cv2": "opencv-python-headless", "yaml": "pyyaml", "PIL": "pillow",
    "tqdm": "tqdm", "torch": "torch", "torchvision": "torchvision", "lightning": "lightning",
    "torchmetrics": "torchmetrics", "hydra": "hydra-core", "omegaconf": "hydra-core",
    "tensorboard": "tensorboard", "onnx": "onnx", "onnxruntime": "onnxruntime",
    "matplotlib": "matplotlib", "scipy": "scipy", "pycocotools": "pycocotools", "gtsam": "gtsam",
    "isal": "isal",
}  # fmt: skip
"""Import name -> distribution of every required dependency (pyproject's ``dependencies``)."""


def _requirement(dist: str) -> str:
    """``dist`` with the version range uss-slam's metadata asks for (``'torch>=2.6'``)."""
    try:
        for line in metadata.requires("uss-slam") or []:
            name = line.split(";")[0].strip()
            if name.lower().replace("_", "-").startswith(dist) and "extra ==" not in line:
                return f"'{name}'"
    except metadata.PackageNotFoundError:
        pass
    return dist


def missing_package_line(prog: str, error: ModuleNotFoundError) -> str | None:
    """The one line for a required package that is not installed, else None."""
    top = (error.name or "").split(".")[0]
    dist = REQUIRED.get(top)
    if dist is None:
        return None
    return (
        f"{prog}: error: the required package {dist} (import {top}) is not installed in "
        f"{sys.executable}; install it with: pip install {_requirement(dist)} (or reinstall "
        "uss-slam with its dependencies)"
    )


MEMORY_LINE = (
    "out of memory: this machine (or a memory limit such as ulimit -v) cannot hold what these "
    "settings need; use smaller images, fewer frames or fewer workers"
)


ADDRESS_SPACE_FLOOR = 512 * 2**20
"""Bytes of address space (``ulimit -v``) below which a script cannot load its libraries:
numpy and OpenCV alone map 453 MB (``VmPeak`` after importing them, measured), and under a
limit between about 300 and 460 MB OpenCV's import crashes the process (SIGSEGV) instead of
failing. Scripts that import torch need more; they fail with an ``ImportError`` (one line)."""


def address_space_line(prog: str) -> str | None:
    """The one line for an address-space limit below :data:`ADDRESS_SPACE_FLOOR`, else None."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY or soft >= ADDRESS_SPACE_FLOOR:
        return None
    return (
        f"{prog}: error: out of memory: ulimit -v allows {soft // 2**20} MB of address space; "
        f"loading the script's libraries (numpy, OpenCV) takes about "
        f"{ADDRESS_SPACE_FLOOR // 2**20} MB; raise the limit"
    )


class _Terminated(KeyboardInterrupt):
    """A stopping signal before the script handles signals itself (raised by
    :func:`on_stopping_signal`)."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def on_stopping_signal(signum: int, frame: object) -> None:
    """The handler of :data:`TERMINATING` from the script's start until its own handling
    starts (and again once that ends): the signal as an interrupt, the one line."""
    raise _Terminated(signum)


UNASSIGNED = (signal.SIGUSR1, signal.SIGUSR2, signal.SIGALRM)
"""Signals with no meaning of their own (``kill -USR1``, a batch system's warning before a
time limit, an ``alarm``), whose default, as SIGTERM's, ends the process at once with no
cleanup: a script takes them as SIGTERM where nothing else in the process handles them
(:func:`taken`)."""

TERMINATING = (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGXCPU, *UNASSIGNED)
"""The signals besides Ctrl-C that stop a script with its one line (``kill``; the terminal
closed; Ctrl-\\ and a CPU-time limit reached, ``ulimit -St`` or a batch system's, which
Python leaves to the kernel's default: a core dump, no cleanup; :data:`UNASSIGNED`)."""


def taken(sig: int, handler: object) -> bool:
    """Whether a script handles ``sig`` as SIGTERM, its handler now being ``handler``: not a
    signal ignored (``nohup``'s SIGHUP), nor one of :data:`UNASSIGNED` that another handler
    already takes (submitit's jobs take SIGUSR2, Lightning SIGUSR1, for a requeue), nor, in a
    SLURM job, SIGUSR1 or SIGUSR2 (``sbatch --signal``'s warning, which Lightning and submitit
    take when they start, after the script)."""
    if handler is signal.SIG_IGN:
        return False
    if sig not in UNASSIGNED:
        return True
    if sig != signal.SIGALRM and "SLURM_JOB_ID" in os.environ:
        return False
    return handler in (signal.SIG_DFL, None, on_stopping_signal)


def openmp_threads_checked(prog: str) -> None:
    """An ``OMP_NUM_THREADS`` that OpenMP does not take (``0``, ``-1``, ``''``, ``abc``: it wants
    a positive count, or a list of them, ``4,2``) is ignored by it with a line of its own
    (libgomp's ``Invalid value for environment variable OMP_NUM_THREADS``, once torch is
    loaded); here it is one warning line of the script's, and removed from the environment,
    so that neither torch nor a process the script starts prints libgomp's."""
    value = os.environ.get("OMP_NUM_THREADS")
    if value is None:
        return
    counts = value.split(",")
    if all(c.strip().lstrip("+").isdigit() and int(c.strip().lstrip("+")) > 0 for c in counts):
        return
    del os.environ["OMP_NUM_THREADS"]
    print(f"{prog}: warning: OMP_NUM_THREADS={value!r}: expected a positive number of threads "
          "(or a list of them, 4,2); ignored, as OpenMP ignores it", file=sys.stderr)  # fmt: skip


def close_open_bars() -> None:
    """Close every progress bar still open, before a script's last line (``interrupted``, an
    error). A bar left open by an interrupt or an error is held by a frame of its traceback;
    closed only when that traceback is freed, after the line, tqdm would draw it again below
    it. Closed here it keeps its last state above the line and draws nothing after it."""
    tqdm_module = sys.modules.get("tqdm.std")
    if tqdm_module is None:  # never imported: no bar
        return
    for bar in list(getattr(tqdm_module.tqdm, "_instances", ())):
        with contextlib.suppress(Exception):  # (a closed stream: nothing to draw on)
            bar.close()


def _interrupted(prog: str, error: KeyboardInterrupt) -> int:
    """The line and exit code of an interrupt that reached :func:`launch`."""
    close_open_bars()
    signum = getattr(error, "signum", signal.SIGINT)
    named = "" if signum == signal.SIGINT else f" ({signal.Signals(signum).name})"
    print(f"{prog}: interrupted{named}", file=sys.stderr)
    return 128 + int(signum)


def launch(prog: str) -> int | None:
    """Run console script ``prog`` (its module's ``main``) with the lines above; ``prog
    --version`` prints ``<prog> <uss-slam's version>`` (every script, Hydra's apps included,
    whose own flag would print Hydra's version), wherever it is on the command line (before a
    ``--``), as argparse's own version flags do."""
    if "--version" in sys.argv[1:][: (sys.argv + ["--"]).index("--", 1) - 1]:  # anywhere
        from importlib.metadata import version

        print(f"{prog} {version('uss-slam')}")
        return 0
    without_optimize()
    in_utf8_mode()
    # a number of more than 4300 digits is out of its key's range, which the range check says
    # naming the key; Python's own limit would stop its conversion first with a line of its own
    sys.set_int_max_str_digits(0)
    openmp_threads_checked(prog)
    line = address_space_line(prog) or working_folder_line(prog)
    if line is not None:  # before any import that could crash on it
        print(line, file=sys.stderr)
        return 1
    stdout.guard()
    # every plot is drawn into a file (Agg); a backend set for interactive use is not the
    # scripts' (a notebook's module://matplotlib_inline... fails matplotlib's import here)
    os.environ["MPLBACKEND"] = "Agg"
    # onnxruntime writes a device id under ~/.cache/Microsoft/DeveloperTools, a file outside
    # the outputs, and where it cannot (a read-only home folder) prints its own coloured
    # warning on every import; the scripts ask it not to (a value the user set stays)
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    private_matplotlib_folder()
    quiet_known_warnings()
    # until the script's own handling starts (its argument checks come first): a signal at
    # any point of a run is its one line, never the kernel's default (restoring the default
    # after the imports left a second-long window in which SIGTERM or SIGHUP killed it)
    with contextlib.suppress(ValueError):  # not the main thread (a test): no handler
        for sig in TERMINATING:
            if taken(sig, signal.getsignal(sig)):  # (nohup: SIGHUP stays ignored)
                signal.signal(sig, on_stopping_signal)
    try:
        torch_without_working_folder(prog)
        main: Callable[[], int | None] = importlib.import_module(SCRIPTS[prog]).main
    except KeyboardInterrupt as error:  # Ctrl-C or SIGTERM during the imports
        return _interrupted(prog, error)
    except ModuleNotFoundError as error:
        line = missing_package_line(prog, error)
        if line is None:
            raise
        print(line, file=sys.stderr)
        return 1
    except ImportError as error:  # a compiled library that cannot be loaded (mapped)
        first = (str(error).strip().splitlines() or [type(error).__name__])[0]
        print(
            f"{prog}: error: cannot load a required library ({first}); too little memory (a "
            "limit such as ulimit -v) or a broken installation",
            file=sys.stderr,
        )
        return 1
    try:
        return main()
    except KeyboardInterrupt as error:  # one that came before the script's own handling
        return _interrupted(prog, error)
    except ModuleNotFoundError as error:  # a required package imported where it is first used
        line = missing_package_line(prog, error)
        if line is None:
            raise
        print(line, file=sys.stderr)
        return 1
    except Exception as error:
        if out_of_memory(error):
            print(f"{prog}: error: {MEMORY_LINE}", file=sys.stderr)
            return 1
        from uss_slam.core.errors import UssSlamError

        if not isinstance(error, UssSlamError):  # raised outside the script's own handling
            raise
        close_open_bars()
        print(f"{prog}: error: {(str(error).strip().splitlines() or [''])[0]}", file=sys.stderr)
        return int(getattr(error, "exit_code", 1))


def private_matplotlib_folder() -> None:
    """Matplotlib keeps its settings and font cache under ``$XDG_CONFIG_HOME`` and
    ``$XDG_CACHE_HOME`` (``~/.config``, ``~/.cache``); where it cannot create or write them (a
    read-only home folder) it prints two lines of its own on every import (``mkdir -p failed``,
    ``Matplotlib created a temporary cache directory``). There the scripts give it a temporary
    folder of their own (``MPLCONFIGDIR``, removed at the end) without a word. A
    ``MPLCONFIGDIR`` the user set stays."""
    if "MPLCONFIGDIR" in os.environ:
        return
    home = os.path.expanduser("~")
    for variable, default in (("XDG_CONFIG_HOME", ".config"), ("XDG_CACHE_HOME", ".cache")):
        folder = os.path.join(os.environ.get(variable) or os.path.join(home, default), "matplotlib")
        existing = folder
        while not os.path.lexists(existing) and os.path.dirname(existing) != existing:
            existing = os.path.dirname(existing)
        if not (os.path.isdir(existing) and os.access(existing, os.W_OK | os.X_OK)):
            break
    else:
        return
    import shutil
    import tempfile

    try:
        private = tempfile.mkdtemp(prefix="uss-slam-matplotlib-")
    except OSError:  # no temporary folder either: matplotlib's own lines
        return
    os.environ["MPLCONFIGDIR"] = private
    atexit.register(shutil.rmtree, private, True)


def without_optimize() -> None:
    """Start the script again without ``PYTHONOPTIMIZE`` (``-O``) when it is set: Hydra's
    override parser needs its asserts (under ``-O`` a dict value such as ``{a:1}`` is an
    ``AttributeError`` inside it), and nothing of the scripts is faster without them. Once."""
    if not sys.flags.optimize or os.environ.get(_RESTARTED) or "PYTHONOPTIMIZE" not in os.environ:
        return
    env = {k: v for k, v in os.environ.items() if k != "PYTHONOPTIMIZE"}
    env[_RESTARTED] = "1"
    if sys.stdout is not None:
        sys.stdout.flush()
    os.execve(sys.executable, [sys.executable, *sys.argv], env)


_RESTARTED = "USS_SLAM_RESTARTED_WITHOUT_OPTIMIZE"


def in_utf8_mode() -> None:
    """Start the script again in Python's UTF-8 mode (``PYTHONUTF8=1``, for it and the processes
    it starts) when the locale's encoding is not UTF-8 and the mode is off: under ``LC_ALL=C``
    with ``PYTHONUTF8=0`` a non-ASCII path arrives as undecodable bytes that no JSON record, plot
    title or ONNX file name can hold. Python itself turns the mode on for the C locale unless
    ``PYTHONUTF8=0`` says not to; the scripts need it whatever the locale. Once."""
    if sys.flags.utf8_mode or os.environ.get(_RESTARTED_UTF8):
        return
    if codecs.lookup(sys.getfilesystemencoding()).name == "utf-8":
        return
    env = {**os.environ, "PYTHONUTF8": "1", _RESTARTED_UTF8: "1"}
    if sys.stdout is not None:
        sys.stdout.flush()
    os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], env)


_RESTARTED_UTF8 = "USS_SLAM_RESTARTED_IN_UTF8_MODE"


HYDRA_APPS = ("uss-slam", "uss-train", "uss-export", "uss-experiments")
"""The scripts that are Hydra apps: Hydra needs the working folder (``hydra.runtime.cwd``)."""


def working_folder_line(prog: str) -> str | None:
    """The error line of a Hydra app started in a working folder that was deleted (Hydra's
    own start would be a traceback), else None. The other scripts need it only for a relative
    path, which the path layer refuses by its key."""
    from uss_slam.core.paths import working_folder_gone  # standard library only

    if prog not in HYDRA_APPS or not working_folder_gone():
        return None
    return (f"{prog}: error: the working folder no longer exists (it was deleted); run "
            "from an existing folder")  # fmt: skip


TORCH_LATER = {"uss-eval": ("uss_slam.export",)}
"""The scripts besides the Hydra apps that may import torch while they run (``uss-eval`` of a
``.ckpt``) -> the modules that import it and the libraries that need a working folder when
imported (torch's oneMKL, ``torch._dynamo``). ``uss-demo``'s training stage needs one to run
too (Hydra's composition, Lightning): it refuses, before its data stage, to start one."""


def torch_without_working_folder(prog: str) -> None:
    """Import torch from ``/`` when the working folder was deleted and ``prog`` may need it,
    then go back into the deleted folder: Intel oneMKL (in torch's ``libtorch_cpu``) cannot be
    loaded without a working folder (``Intel oneMKL FATAL ERROR``: the process ends, after a
    stage's work, with no line of the script's own). Loaded once, it works anywhere; back in
    the deleted folder, a relative path is still refused by the path layer, naming its key."""
    from uss_slam.core.paths import working_folder_gone  # standard library only

    if prog not in TORCH_LATER or not working_folder_gone():
        return
    try:
        here = os.open(".", os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.chdir("/")
        try:
            for module in TORCH_LATER[prog]:
                importlib.import_module(module)
        except ImportError:  # the script's own line when it needs it
            pass
    finally:
        os.fchdir(here)
        os.close(here)


def out_of_memory(error: BaseException) -> bool:
    """Whether ``error`` (or one in its cause chain) is an allocation that failed: Python's
    ``MemoryError``, OpenCV's ``cv2.error`` with code ``StsNoMem`` (-4), or torch's CPU
    allocator's ``RuntimeError``."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, MemoryError):
            return True
        if type(current).__module__ == "cv2" and getattr(current, "code", None) == CV2_NO_MEMORY:
            return True
        if isinstance(current, RuntimeError) and TORCH_NO_MEMORY in str(current):
            return True  # torch's CPU allocator: a RuntimeError, its only mark this text
        current = current.__cause__ or current.__context__
    return False


CV2_NO_MEMORY = -4
"""``cv2.Error.StsNoMem``: OpenCV could not allocate."""
TORCH_NO_MEMORY = "DefaultCPUAllocator: can't allocate memory"
"""The text of torch's ``RuntimeError`` when its CPU allocator fails."""


def _entry(prog: str) -> Callable[[], None]:
    def run() -> None:
        ended: dict[str, int] = {}
        atexit.register(_after_the_work, prog, ended)  # first registered: it runs last
        try:
            code = launch(prog)
        except SystemExit as stop:  # a Hydra app's own exit (its one line printed)
            if not isinstance(stop.code, int | None):
                raise
            code = stop.code
        stdout.report_lost(prog)
        ended["code"] = int(code or 0)
        _record_late_signals(ended)
        sys.exit(code)

    run.__name__ = run.__qualname__ = prog.replace("-", "_")
    run.__doc__ = f"``{prog}``: :func:`launch`."
    return run


def _record_late_signals(ended: dict[str, int]) -> None:
    """The script is done and has said so: a Ctrl-C, SIGTERM or SIGHUP during the interpreter's
    shutdown (joining threads, the exit callbacks of libraries) stops nothing any more and must
    not kill the process by the signal after its outputs were written; it is recorded, and
    :func:`_after_the_work` says so at the very end (a signal ignored, as under ``nohup``,
    stays ignored)."""

    def late(signum: int, frame: object) -> None:
        ended.setdefault("signal", signum)

    for sig in (signal.SIGINT, *TERMINATING):
        try:
            if signal.getsignal(sig) is not signal.SIG_IGN:
                signal.signal(sig, late)
        except ValueError:  # not the main thread
            pass


def _after_the_work(prog: str, ended: dict[str, int]) -> None:
    """The last exit callback of a console script, and the last Python it runs: what the
    interpreter's teardown would still do for the outputs (:func:`close_open_files`), then the
    process ends here (``os._exit``), so that no signal can come after the script's last word
    (one that came during the teardown was ignored: exit 0 and no line). After a signal that
    came once the work was done, one line saying so and the signal's exit code (128 + its
    number, as an interrupt's), the outputs being complete; a failed run keeps its own code.
    A script that ended by an exception (its traceback printed) ends the usual way."""
    if "code" not in ended:
        for sig in (signal.SIGINT, *TERMINATING):
            with contextlib.suppress(ValueError):  # not the main thread
                signal.signal(sig, signal.SIG_IGN)
        return
    code = ended["code"]
    close_open_files()
    with contextlib.suppress(ValueError, OSError, AttributeError):  # (no such call, or a thread)
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, *TERMINATING})
        pending = signal.sigpending() & {signal.SIGINT, *TERMINATING}
        if pending and "signal" not in ended:  # one that came after the last bytecode's check
            ended["signal"] = min(int(s) for s in pending)
    code = _flush_std(code)
    signum = ended.get("signal")
    if signum is not None and code == 0:
        named = "" if signum == signal.SIGINT else f" ({signal.Signals(signum).name})"
        with contextlib.suppress(OSError, ValueError, AttributeError):
            print(f"{prog}: interrupted{named} after the work was done; its outputs are "
                  "complete", file=sys.stderr, flush=True)  # fmt: skip
        code = 128 + int(signum)
    os._exit(code)


def close_open_files() -> None:
    """Close every file object still open (text wrappers before the buffers and raw files under
    them), as the interpreter's teardown would when it frees them: a file a library left open
    keeps everything written to it (a compressed file its trailer). The standard streams stay
    (:func:`_flush_std`)."""
    import _io
    import gc

    gc.collect()  # the unreachable ones are freed (closed) now
    kinds = (_io._TextIOBase, _io._BufferedIOBase, _io._IOBase)  # the outer ones first
    # (by type alone: isinstance would read each object's __class__, which some libraries'
    # deprecated objects answer with a warning)
    found = [o for o in gc.get_objects() if issubclass(type(o), kinds[2]) and not _standard(o)]
    for kind in kinds:
        for item in found:
            if issubclass(type(item), kind):
                with contextlib.suppress(Exception):
                    if not item.closed:
                        item.close()


def _standard(stream: object) -> bool:
    """Whether ``stream`` is (or wraps, or is under) stdin, stdout or stderr."""
    try:
        return stream.fileno() in (0, 1, 2)  # type: ignore[attr-defined]
    except Exception:  # noqa: BLE001 (no file descriptor: a BytesIO, a closed file)
        return False


def _flush_std(code: int) -> int:
    """Flush stdout and stderr, without Python's ``Exception ignored`` text and exit code 120
    for one that cannot be written (what was lost there was said by
    :func:`uss_slam.core.stdout.report_lost`)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            if stream is not None:
                stream.flush()
    return code


uss_synth = _entry("uss-synth")
uss_traj = _entry("uss-traj")
uss_slam = _entry("uss-slam")
uss_vocab = _entry("uss-vocab")
uss_train = _entry("uss-train")
uss_export = _entry("uss-export")
uss_demo = _entry("uss-demo")
uss_eval = _entry("uss-eval")
uss_experiments = _entry("uss-experiments")

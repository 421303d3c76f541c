"""The console scripts' entry points (``uss_slam.core.launch``): a required package that is
missing and running out of memory are one line and exit code 1, in every script."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomllib

from uss_slam.core import launch

ROOT = Path(__file__).resolve().parents[2]


def test_every_required_dependency_has_its_import_name() -> None:
    """Each distribution of pyproject's ``dependencies`` is named in :data:`launch.REQUIRED`
    (a dependency added there must be added here, or its absence would be a traceback)."""
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {dep.split(">")[0].split("<")[0].split("=")[0].strip().lower() for dep in deps}
    assert names == set(launch.REQUIRED.values())


MISSING_YAML = (
    "import sys; sys.modules['yaml'] = None; from uss_slam.core.launch import launch; "
    "sys.exit(launch(sys.argv[1]))"
)
"""A console script where ``import yaml`` fails as it does without PyYAML installed."""


@pytest.mark.parametrize("prog", ["uss-synth", "uss-traj", "uss-slam"])
def test_a_missing_required_package_is_one_line(prog: str) -> None:
    """(Scripts whose modules import PyYAML when imported; every script runs through
    :func:`launch.launch`, as ``tests/test_cli_matrix.py`` checks in pyproject.toml. In a
    process of its own: importing a script's modules again here would leave two copies.)"""
    done = subprocess.run(
        [sys.executable, "-c", MISSING_YAML, prog], capture_output=True, text=True, timeout=300
    )
    err = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(err) == 1, done.stderr
    assert err[0].startswith(
        f"{prog}: error: the required package pyyaml (import yaml) is not installed in "
    )
    assert "install it with: pip install 'pyyaml>=6.0'" in err[0]


MISSING_MATPLOTLIB = (
    "import sys; sys.modules['matplotlib'] = None; from uss_slam.core.launch import launch; "
    "sys.argv = sys.argv[1:]; sys.exit(launch(sys.argv[0]))"
)
"""A console script where ``import matplotlib`` fails (it is imported where it is first used)."""


def test_a_missing_package_imported_where_it_is_used_is_one_line(tmp_path: Path) -> None:
    """``uss-traj ate --plot``: matplotlib, imported only for the figure, is missing: the same
    one line as a package missing when the script's modules are imported."""
    gt = tmp_path / "gt.txt"
    gt.write_text("".join(f"{t}.0 {t} 0 0 0 0 0 1\n" for t in range(5)))
    done = subprocess.run(
        [sys.executable, "-c", MISSING_MATPLOTLIB, "uss-traj", "ate", str(gt), str(gt),
         "--plot", str(tmp_path / "p.png")],
        capture_output=True, text=True, timeout=300, env={"PATH": "/usr/bin:/bin"},
        cwd=tmp_path,
    )  # fmt: skip
    err = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(err) == 1, done.stderr
    assert err[0].startswith("uss-traj: error: the required package matplotlib (import "
                             "matplotlib) is not installed in ")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gt.txt"]


SMALL_ADDRESS_SPACE = (
    "import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (400 << 20, 400 << 20)); "
    "from uss_slam.core.launch import launch; sys.argv = sys.argv[1:]; "
    "sys.exit(launch(sys.argv[0]))"
)


def test_an_address_space_too_small_to_load_the_libraries_is_one_line(tmp_path: Path) -> None:
    """``ulimit -v`` 400 MB: OpenCV's import would crash the process (SIGSEGV); the one line
    comes first, and nothing is written."""
    done = subprocess.run(
        [sys.executable, "-c", SMALL_ADDRESS_SPACE, "uss-eval", "m.onnx", "--sequence", "s",
         "--out", str(tmp_path / "e")],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    err = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(err) == 1, done.stderr
    assert err[0] == (
        "uss-eval: error: out of memory: ulimit -v allows 400 MB of address space; loading the "
        "script's libraries (numpy, OpenCV) takes about 512 MB; raise the limit"
    )
    assert list(tmp_path.iterdir()) == []


def _opencv_no_memory() -> BaseException:
    """The ``cv2.error`` OpenCV raises when an allocation fails (``ulimit -v``)."""
    import cv2

    error = cv2.error("OpenCV(4) alloc.cpp:73: error: (-4:Insufficient memory) Failed to allocate")
    error.code = -4  # cv2.Error.StsNoMem, as OpenCV sets it
    return error


def _wrapped_memory_error() -> BaseException:
    error = RuntimeError("a library's own error")
    error.__cause__ = MemoryError()
    return error


@pytest.mark.parametrize("make", [MemoryError, _wrapped_memory_error, _opencv_no_memory])
def test_running_out_of_memory_is_one_line(make, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    from uss_slam.synthetic import cli

    def main() -> int:
        raise make()

    monkeypatch.setattr(cli, "main", main)
    assert launch.launch("uss-synth") == 1
    assert capsys.readouterr().err == f"uss-synth: error: {launch.MEMORY_LINE}\n"


def test_other_errors_keep_their_traceback(monkeypatch: pytest.MonkeyPatch) -> None:
    from uss_slam.synthetic import cli

    def main() -> int:
        raise ValueError("an internal error")

    monkeypatch.setattr(cli, "main", main)
    with pytest.raises(ValueError, match="an internal error"):
        launch.launch("uss-synth")


@pytest.mark.parametrize(("error", "code", "line"), [
    (KeyboardInterrupt(), 130, "uss-export: interrupted"),
    (launch._Terminated(), 143, "uss-export: interrupted (SIGTERM)"),
    (launch._Terminated(signal.SIGQUIT), 131, "uss-export: interrupted (SIGQUIT)"),
])  # fmt: skip
def test_an_interrupt_during_the_imports_is_the_one_line(
    monkeypatch, capsys, error: BaseException, code: int, line: str
) -> None:
    """Ctrl-C or SIGTERM while the script's libraries load (seconds on a busy machine): the
    same line and exit code as later in the run, no import traceback."""

    def interrupted(name: str) -> None:
        raise error

    monkeypatch.setattr(launch.importlib, "import_module", interrupted)
    assert launch.launch("uss-export") == code
    assert capsys.readouterr().err.strip().splitlines() == [line]


def test_a_missing_package_inside_a_hydra_app_is_the_same_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``_target_`` whose module imports a required package that is missing: the schema's
    lookup lets the import's own error through (not Hydra's logged "Error getting object"), and
    the Hydra apps' handler finds it in a wrapped error's chain."""
    from uss_slam.core.cli import _missing_package
    from uss_slam.core.schema.targets import _import_module_of

    (tmp_path / "needs_cv2.py").write_text("import cv2\n\nclass Thing:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(sys.modules, "cv2", None)
    with pytest.raises(ModuleNotFoundError) as caught:
        _import_module_of("needs_cv2.Thing")
    assert caught.value.name == "cv2"
    _import_module_of("no_such_package.module.Thing")  # left to Hydra's lookup: no error here
    wrapped = RuntimeError("Error locating target 'needs_cv2.Thing'")
    wrapped.__cause__ = caught.value
    line = _missing_package("uss-train", wrapped)
    assert line is not None and line.startswith(
        "uss-train: error: the required package opencv-python-headless (import cv2) is not "
    )
    assert _missing_package("uss-train", RuntimeError("other")) is None


LATE_SIGNAL = """
import signal, sys, threading, time, types
from uss_slam.core import launch

def main():
    # a library's thread the interpreter joins at its shutdown (a writer, a teardown)
    threading.Thread(target=time.sleep, args=(float(sys.argv[1]),)).start()
    print("done", flush=True)
    return int(sys.argv[2])

module = types.ModuleType("late_script")
module.main = main
sys.modules["late_script"] = module
launch.SCRIPTS["uss-late"] = "late_script"
launch._entry("uss-late")()
"""


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGHUP, 0), (signal.SIGINT, 0),
                                           (signal.SIGTERM, 1), (signal.SIGQUIT, 0),
                                           (None, 0)])  # fmt: skip
def test_a_signal_after_the_work_is_done_is_one_line_and_kills_nothing(
    sig: signal.Signals | None, code: int
) -> None:
    """Once the script has finished and said so, a Ctrl-C, SIGTERM or SIGHUP (the terminal
    closed) during the interpreter's shutdown does not kill the process by the signal (it did:
    exit code -2 while onnxruntime and torch tore down), nor goes unsaid (exit 0 with no
    line): one line that the work was done and the signal's exit code; a run that failed keeps
    its own code."""

    def as_from_a_terminal() -> None:  # (a test run under nohup or `&` ignores them)
        for each in (signal.SIGHUP, signal.SIGINT):
            signal.signal(each, signal.SIG_DFL)

    proc = subprocess.Popen([sys.executable, "-c", LATE_SIGNAL, "1.5", str(code)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=as_from_a_terminal)  # fmt: skip
    assert proc.stdout is not None and proc.stdout.readline() == "done\n"
    if sig is not None:
        time.sleep(0.3)  # main has returned: the shutdown joins the thread
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    if sig is None or code != 0:
        assert (proc.returncode, err) == (code, "")
        return
    named = "" if sig == signal.SIGINT else f" ({sig.name})"
    assert proc.returncode == 128 + sig, err
    assert err.splitlines() == [
        f"uss-late: interrupted{named} after the work was done; its outputs are complete"
    ]


SLOW_TEARDOWN = """
import gzip, sys, time, types
from uss_slam.core import launch

class Teardown:  # a library's object whose teardown takes a while (torch's, onnxruntime's)
    def __del__(self):
        time.sleep(3)

def main():
    module.kept = Teardown()
    module.text = open(sys.argv[1] + ".txt", "w")  # left open, its buffer not flushed
    module.text.write("x" * 100)
    module.packed = gzip.open(sys.argv[1] + ".gz", "wt")  # left open: no trailer yet
    module.packed.write("y" * 100)
    print("done", flush=True)
    return 0

module = types.ModuleType("late_script")
module.main = main
sys.modules["late_script"] = module
launch.SCRIPTS["uss-late"] = "late_script"
launch._entry("uss-late")()
"""


def test_a_signal_during_the_interpreters_teardown_is_not_dropped(tmp_path: Path) -> None:
    """Ctrl-C while the interpreter tears down after the script's last exit callback (a
    library's objects freed, a file flushed) was ignored: exit 0 and no line. The process ends
    with the last callback now, having closed what the teardown would have closed (a file left
    open keeps its buffered text, a gzip file its trailer): a signal sent after ``done`` either
    finds it gone (exit 0) or is the one line and 130."""
    import gzip

    def as_from_a_terminal() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    proc = subprocess.Popen([sys.executable, "-c", SLOW_TEARDOWN, str(tmp_path / "f")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=as_from_a_terminal)  # fmt: skip
    assert proc.stdout is not None and proc.stdout.readline() == "done\n"
    time.sleep(1.0)  # the teardown would be sleeping in Teardown.__del__ now
    gone = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    if gone:
        assert (proc.returncode, err) == (0, "")
    else:
        assert proc.returncode == 130, err
        assert err.splitlines() == [
            "uss-late: interrupted after the work was done; its outputs are complete"
        ]
    assert (tmp_path / "f.txt").read_text() == "x" * 100
    with gzip.open(tmp_path / "f.gz", "rt") as packed:
        assert packed.read() == "y" * 100


@pytest.mark.parametrize(
    ("prog", "args"),
    [("uss-synth", []), ("uss-slam", []), ("uss-synth", ["voc", "--out", "x"]),
     ("uss-slam", ["progress=false"]), ("uss-train", ["-m"])],
)  # fmt: skip
def test_version_flag(prog: str, args: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """``--version`` anywhere: the project's version, exit 0 (argparse would name a missing
    subcommand, Hydra print its own version)."""
    from importlib.metadata import version

    monkeypatch.setattr(sys, "argv", [prog, *args, "--version"])
    assert launch.launch(prog) == 0
    assert capsys.readouterr().out == f"{prog} {version('uss-slam')}\n"


@pytest.mark.parametrize("value", ["0", "-1", "", "abc", "2,0"])
def test_an_openmp_thread_count_openmp_ignores_is_one_warning_line(value: str) -> None:
    """libgomp printed its own ``Invalid value for environment variable OMP_NUM_THREADS``
    once torch was loaded (uss-train, uss-export, uss-eval of a checkpoint)."""
    code = (
        "from uss_slam.core.launch import openmp_threads_checked; import os; "
        "openmp_threads_checked('prog'); assert 'OMP_NUM_THREADS' not in os.environ; "
        "import torch; torch.ones(4).sum()"
    )
    env = {**os.environ, "OMP_NUM_THREADS": value}
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stderr.splitlines() == [
        f"prog: warning: OMP_NUM_THREADS={value!r}: expected a positive number of threads (or a "
        "list of them, 4,2); ignored, as OpenMP ignores it"
    ]


@pytest.mark.parametrize("value", ["1", "4,2", " +3"])
def test_an_openmp_thread_count_openmp_takes_is_kept(value: str) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": value}
    code = "from uss_slam.core.launch import openmp_threads_checked; openmp_threads_checked('p')"
    code += "; import os; print(os.environ['OMP_NUM_THREADS'])"
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert (run.stdout, run.stderr) == (value + "\n", "")


def test_a_non_ascii_path_under_the_c_locale_without_utf8_mode_is_a_normal_run(
    tmp_path: Path,
) -> None:
    """``LC_ALL=C PYTHONUTF8=0``: the script starts again in UTF-8 mode, so a folder named with
    an emoji is an ordinary path (it was written into the run's JSON record as undecodable
    bytes: a traceback)."""
    env = {**os.environ, "LC_ALL": "C", "PYTHONUTF8": "0"}
    env.pop("LANG", None)
    seq, out = tmp_path / "seq \N{GRINNING FACE}", tmp_path / "o \N{GRINNING FACE}"
    bin_dir = Path(sys.executable).parent
    synth = [str(bin_dir / "uss-synth"), "sequence", "--preset", "static_xyz", "--frames", "3",
             "--size", "48x32", "--out", str(seq), "--quiet"]  # fmt: skip
    subprocess.run(synth, check=True, env=env, capture_output=True)
    run = subprocess.run(
        [str(bin_dir / "uss-slam"), f"sequence.path='{seq}'", f"out_dir='{out}'", "progress=false"],
        env=env, capture_output=True, text=True, encoding="utf-8", errors="replace",
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    assert (out / "run.json").is_file() and (out / "metrics.json").is_file()


def test_a_number_of_more_digits_than_python_converts_is_out_of_its_keys_range(
    tmp_path: Path,
) -> None:
    """4401 digits: the range check's line naming the key, not Python's conversion limit."""
    big = "1" + "0" * 4400
    bin_dir = Path(sys.executable).parent
    run = subprocess.run(
        [str(bin_dir / "uss-experiments"), f"out_dir={tmp_path / 'x'}", "dry_run=true",
         f"slam.repeats={big}"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode == 1, run.stderr
    assert run.stderr.startswith("uss-experiments: error: slam.repeats: expected an integer")
    assert len(run.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x" / "jobs").exists()  # no plan (Hydra's own record aside)


EARLY_SIGNAL = """
import os, signal, sys, time, types
from uss_slam.core import launch

def main():
    # the script's argument checks, before its own handling of signals starts
    os.kill(os.getpid(), int(sys.argv[1]))
    time.sleep(5)
    return 0

module = types.ModuleType("early_script")
module.main = main
sys.modules["early_script"] = module
launch.SCRIPTS["uss-early"] = "early_script"
launch._entry("uss-early")()
"""


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGTERM, signal.SIGUSR1])
def test_a_signal_before_the_scripts_own_handling_starts_is_the_one_line(
    sig: signal.Signals,
) -> None:
    """After the imports and before the script handles signals itself (its argument checks,
    about half a second of ``uss-eval compare``), SIGHUP or SIGTERM killed the process by the
    kernel's default (no line, exit -1): the handler of the imports now stays until the
    script's own starts."""

    def as_from_a_terminal() -> None:  # (a test run under nohup ignores SIGHUP)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)

    run = subprocess.run([sys.executable, "-c", EARLY_SIGNAL, str(int(sig))], capture_output=True,
                         text=True, timeout=60, preexec_fn=as_from_a_terminal)  # fmt: skip
    assert run.returncode == 128 + sig, run.stderr
    assert run.stderr.splitlines() == [f"uss-early: interrupted ({sig.name})"]

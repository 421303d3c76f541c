"""SIGTERM (``kill``, ``timeout``, a scheduler's preemption, a container stop) is handled as
Ctrl-C by every console script: the same cleanup, exit code 143 and the one line
``<prog>: interrupted (SIGTERM)``; Ctrl-C keeps exit code 130 and ``<prog>: interrupted``.

First every interrupt case of the console-script matrix (``tests/test_cli_matrix.py``) with a
real signal sent to this process where the case raised ``KeyboardInterrupt``; then real
console-script processes stopped by a signal, and the temporary files of a ``uss-export``
killed with kill -9, which the next export removes.
"""

from __future__ import annotations

import importlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from test_cli_matrix import (  # noqa: F401 (world: the matrix's fixture)
    CASES,
    Case,
    earlier_export,
    interrupt_after,
    run_console_script,
    snapshot,
    world,
)

from uss_slam.core.cli import INTERRUPTED, TERMINATED

SIGNALS = {
    "SIGINT": (signal.SIGINT, INTERRUPTED),
    "SIGTERM": (signal.SIGTERM, TERMINATED),
    "SIGQUIT": (signal.SIGQUIT, 128 + signal.SIGQUIT),  # Ctrl-\: as SIGTERM, not a core dump
}
UNASSIGNED = ["SIGUSR1", "SIGUSR2", "SIGALRM"]  # no meaning of their own; default: die at once
BIN = Path(sys.executable).parent


def signal_and_code(name: str) -> tuple[int, int]:
    """The signal named ``name`` and the exit code it gives (128 + its number but Ctrl-C's)."""
    return SIGNALS.get(name, (signal.Signals[name], 128 + signal.Signals[name]))


def expected_line(line: str, sig: int) -> str:
    """The matrix's Ctrl-C line as it reads after ``sig``."""
    if sig == signal.SIGINT:
        return line
    return line.replace(": interrupted", f": interrupted ({signal.Signals(sig).name})", 1)


def signal_after(monkeypatch: pytest.MonkeyPatch, target: str, calls: int, sig: int) -> None:
    """Make ``module:Object.attr`` send ``sig`` to this process on call ``calls + 1`` (a real
    signal, handled by the console script's handler)."""
    interrupt_after(monkeypatch, target, calls)  # raises KeyboardInterrupt on call calls + 1
    module, _, path = target.partition(":")
    owner = importlib.import_module(module)
    *parents, name = path.split(".")
    for parent in parents:
        owner = getattr(owner, parent)
    raising = getattr(owner, name)

    def wrapper(*args, **kwargs):
        try:
            return raising(*args, **kwargs)
        except KeyboardInterrupt:
            os.kill(os.getpid(), sig)
            time.sleep(5)  # the handler raises before this ends
            raise AssertionError(f"{signal.Signals(sig).name} was not handled") from None

    monkeypatch.setattr(owner, name, wrapper)


INTERRUPT_CASES = [c for c in CASES if c.interrupt is not None]


@pytest.mark.parametrize("sig_name", list(SIGNALS))
@pytest.mark.parametrize("case", [pytest.param(c, id=c.id) for c in INTERRUPT_CASES])
def test_every_interrupt_case_with_a_real_signal(
    case: Case,
    sig_name: str,
    world: dict[str, Path],  # noqa: F811
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    sig, code = SIGNALS[sig_name]
    paths = {**world, "tmp": tmp_path}
    for setup in case.setup:
        setup(paths)
    argv = [arg.format(**paths) for arg in case.argv]
    assert case.interrupt is not None
    signal_after(monkeypatch, *case.interrupt, sig)
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    handlers = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))

    got, _, err = run_console_script(case.prog, argv, monkeypatch, capsys)

    assert got == code, err
    assert err.strip().splitlines() == [expected_line(case.says[0], sig)], err
    assert snapshot(tmp_path) == before  # nothing written; an earlier run or export intact
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers


def test_every_console_script_has_an_interrupt_case() -> None:
    progs = {c.prog for c in INTERRUPT_CASES}
    # uss-train: test_cli_matrix's Ctrl-C test and the process test below; uss-experiments:
    # the process test below
    assert progs >= {"uss-synth", "uss-traj", "uss-vocab", "uss-eval", "uss-demo", "uss-slam",
                     "uss-export"}  # fmt: skip


# ------------------------------------------------------------------------------ processes


def stop(
    command: list[str],
    ready: Callable[[], bool],
    sig: int,
    cwd: Path,
    limit: float = 300,
    group: bool = False,
) -> tuple[int, str]:
    """Start ``command``, send ``sig`` once ``ready()`` (``group``: to its whole process group,
    as ``kill -- -PGID``); (exit code, stderr)."""
    proc = subprocess.Popen(
        command,
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=group,
    )
    deadline = time.monotonic() + limit
    while not ready():
        assert proc.poll() is None, proc.communicate()[1]
        assert time.monotonic() < deadline, "not ready in time"
        time.sleep(0.02)
    if group:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, err


def interrupted(prog: str, sig: int, note: str = "") -> str:
    named = "" if sig == signal.SIGINT else f" ({signal.Signals(sig).name})"
    return f"{prog}: interrupted{named}" + (f"; {note}" if note else "")


@pytest.mark.parametrize("sig_name", list(SIGNALS))
def test_synth_process(sig_name: str, synthetic_sequence, tmp_path: Path) -> None:
    """``uss-synth --overwrite`` stopped while rendering: its partial folder and lock are
    gone, the earlier sequence is as it was."""
    sig, code = SIGNALS[sig_name]
    out = tmp_path / "out" / "seq"
    shutil.copytree(synthetic_sequence(frames=8, size=(160, 120), seed=5), out)
    before = snapshot(out)

    def ready() -> bool:
        partials = list(out.parent.glob(".seq.partial-*"))
        return bool(partials) and len(list((partials[0] / "rgb").glob("*.png"))) >= 2

    got, err = stop(
        [str(BIN / "uss-synth"), "sequence", "--preset", "walking_xyz", "--frames", "400",
         "--size", "160x120", "--out", str(out), "--overwrite", "--quiet"],
        ready, sig, tmp_path,
    )  # fmt: skip
    assert got == code, err
    assert err.strip().splitlines() == [interrupted("uss-synth", sig, "nothing was written")]
    assert sorted(p.name for p in out.parent.iterdir()) == ["seq"]  # no partial, no lock
    assert snapshot(out) == before


@pytest.mark.parametrize("sig_name", [*SIGNALS, "SIGXCPU", *UNASSIGNED])
def test_vocab_process(sig_name: str, synthetic_sequence, tmp_path: Path) -> None:
    """``uss-vocab build`` stopped while clustering: no vocabulary, lock or temporary file.
    SIGXCPU: the kernel's signal at a CPU-time limit (``ulimit -St``, a batch system's);
    SIGUSR1, SIGUSR2, SIGALRM: signals with no meaning of their own, whose default is to die
    at once."""
    sig, code = signal_and_code(sig_name)
    seq = synthetic_sequence(frames=30, size=(320, 240))
    out = tmp_path / "v.txt"
    got, err = stop(
        [str(BIN / "uss-vocab"), "build", str(seq), "--out", str(out), "-k", "10", "-L", "4",
         "--stride", "1"],
        (tmp_path / ".v.txt.lock").is_file, sig, tmp_path,
    )  # fmt: skip
    assert got == code, err
    assert err.strip().splitlines() == [interrupted("uss-vocab", sig)]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # a uss-slam run, then a second one stopped: ~30 s
@pytest.mark.parametrize("sig_name", [*SIGNALS, "SIGUSR2"])
def test_slam_process(sig_name: str, world: dict[str, Path], tmp_path: Path) -> None:  # noqa: F811
    """``uss-slam`` stopped mid-run: the earlier complete run as it was, no staging folder, no
    lock."""
    sig, code = signal_and_code(sig_name)
    out = tmp_path / "run"
    shutil.copytree(world["slam_run"], out)
    before = snapshot(out)
    got, err = stop(
        [str(BIN / "uss-slam"), f"sequence.path={world['seq']}", f"out_dir={out}",
         "progress=false", "segmenter=labels", "compare=[[semantic],[geometry],[semantic,geometry]]"],
        lambda: any(out.glob(".uss-slam-new.*")), sig, tmp_path,
    )  # fmt: skip
    assert got == code, err
    assert err.strip().splitlines() == [interrupted("uss-slam", sig)]
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no lock left
    assert not list(out.glob(".uss-slam-*"))


@pytest.mark.slow  # imports torch and trains: ~30 s
def test_train_process(world: dict[str, Path], tmp_path: Path) -> None:  # noqa: F811
    """``uss-train`` stopped by SIGTERM after its first checkpoints: exit code 143, its line
    last on stderr, the checkpoints whole, no temporary file."""
    from uss_slam.models.checkpoint import read_checkpoint

    ckpts = tmp_path / "run" / "checkpoints"
    got, err = stop(
        [str(BIN / "uss-train"), "experiment=ci", f"data.source.root={world['voc']}",
         f"data.target.roots=[{world['target']}]", f"data.val.roots=[{world['val']}]",
         "data.val.stride=1", f"hydra.run.dir={tmp_path}/run", f"paths.log_dir={tmp_path}/logs",
         "logger=none", "model.max_iters=400"],
        (ckpts / "last.ckpt").is_file, signal.SIGTERM, tmp_path,
    )  # fmt: skip
    assert got == TERMINATED, err
    assert err.strip().splitlines()[-1] == "uss-train: interrupted (SIGTERM)", err
    assert "Traceback" not in err, err
    saved = sorted(ckpts.iterdir())
    assert not [p for p in saved if p.name.endswith(".tmp")]
    read_checkpoint(ckpts / "last.ckpt")


@pytest.mark.slow  # the demo's data stage on two worker processes: ~20 s
@pytest.mark.parametrize("sig_name", [*SIGNALS, "SIGUSR1"])
def test_demo_data_stage_process(sig_name: str, tmp_path: Path) -> None:
    """``uss-demo`` stopped in its data stage (two pool workers rendering): the one line and
    no worker traceback, the workers ended, no staging folder and no lock left. SIGUSR1 goes
    to the whole process group (``kill -USR1 -- -PGID``): the workers too get it."""
    sig, code = signal_and_code(sig_name)
    out = tmp_path / "demo"
    got, err = stop(
        [str(BIN / "uss-demo"), "--out", str(out), "--experiment", "ci", "--until", "data",
         "--quiet"],
        lambda: any(p.name.startswith(".") and "partial" in p.name
                    for p in out.rglob("*") if p.is_dir()),
        sig, tmp_path, group=sig_name in UNASSIGNED,
    )  # fmt: skip
    assert got == code, err
    assert err.strip().splitlines() == [interrupted("uss-demo", sig)], err
    leftovers = [p for p in tmp_path.rglob("*") if "partial" in p.name or p.suffix == ".lock"]
    assert leftovers == []
    alive = subprocess.run(["pgrep", "-f", str(out)], capture_output=True, text=True).stdout
    assert alive.strip() == ""  # no worker left running


@pytest.mark.slow  # three uss-export processes, each importing torch: ~40 s
def test_a_later_export_removes_the_temporaries_of_a_killed_one(
    world: dict[str, Path],  # noqa: F811
    tmp_path: Path,
) -> None:
    """SIGTERM of ``uss-export`` while it writes: exit 143, the earlier export intact, no
    temporary file, no lock. kill -9 leaves its temporaries (no cleanup runs); the next export
    removes them (its own output's only: another output's temporaries stay)."""
    paths = {**world, "tmp": tmp_path}
    earlier_export(paths)
    exports = paths["exports"]
    before = snapshot(exports)
    command = [str(BIN / "uss-export"), f"ckpt_path={world['ckpt']}", "out_dir=exports",
               "num_threads=1"]  # fmt: skip

    def staging() -> bool:
        return any(p.name.endswith(".tmp") for p in exports.iterdir())

    got, err = stop([*command, "hydra.run.dir=hydra_a"], staging, signal.SIGTERM, tmp_path)
    assert got == TERMINATED, err
    assert err.strip().splitlines() == ["uss-export: interrupted (SIGTERM)"], err
    assert snapshot(exports) == before
    assert sorted(p.name for p in exports.iterdir()) == sorted(before)  # no .tmp, no lock

    got, err = stop([*command, "hydra.run.dir=hydra_b"], staging, signal.SIGKILL, tmp_path)
    assert got == -signal.SIGKILL
    left = {p.name for p in exports.iterdir()} - set(before) - {".fake.onnx.lock"}
    assert left and all(n.startswith(".fake.") and n.endswith(".tmp") for n in left), left
    other = exports / ".other.onnx.0123456789ab.tmp"  # another output's: not this export's
    other.write_bytes(b"another export's\n")

    done = subprocess.run(
        [*command, "hydra.run.dir=hydra_c"], cwd=tmp_path, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    names = {p.name for p in exports.iterdir()}
    assert names == {"fake.onnx", "fake.verify.json", other.name}, names

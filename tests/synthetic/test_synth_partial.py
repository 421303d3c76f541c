"""A killed ``uss-synth`` leaves only its marked partial folder, which the next run removes; the
clean-up touches nothing else (unmarked folders, live or foreign owners, other outputs)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from uss_slam.synthetic import render_sequence
from uss_slam.synthetic.output import (
    OUTPUT_MARKER,
    PARTIAL_MARKER,
    clean_stale_partials,
    stale_partials,
)

CLI = "import sys; from uss_slam.synthetic.cli import main; sys.exit(main())"


def _command(out: Path, frames: int, *extra: str) -> list[str]:
    return [sys.executable, "-c", CLI, "sequence", "--preset", "walking_xyz", "--frames",
            str(frames), "--size", "32x24", "--quiet", "--out", str(out), *extra]  # fmt: skip


def _partials(out: Path) -> list[Path]:
    return sorted(out.parent.glob(f".{out.name}.partial-*"))


def _kill_while_rendering(command: list[str], out: Path, frames_written: int = 3) -> int:
    """Start ``command``, SIGKILL it once its partial folder holds ``frames_written`` colour
    frames; returns its pid."""
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    try:
        while True:
            partials = _partials(out)
            if partials and len(list((partials[0] / "rgb").glob("*.png"))) >= frames_written:
                break
            assert proc.poll() is None, f"finished before it could be killed: {proc.stderr}"
            assert time.monotonic() < deadline, "no partial folder appeared"
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    return proc.pid


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@pytest.mark.slow
def test_kill_9_while_rendering_then_rerun(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    pid = _kill_while_rendering(_command(out, 60), out)
    # what is left: no output, one hidden partial folder carrying the marker of the dead process
    # and the output's lock file (unlocked by the kernel when the process died)
    assert not out.exists()
    (partial,) = _partials(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".seq.lock", partial.name]
    marker = json.loads((partial / PARTIAL_MARKER).read_text())
    assert marker == {"pid": pid, "host": socket.gethostname(), "out": str(out)}
    assert not (partial / OUTPUT_MARKER).exists() and not (partial / "rgb.txt").exists()
    assert stale_partials(out) == [partial]
    # the rerun removes it (saying so) and writes the complete sequence
    rerun = subprocess.run(_command(out, 60), capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert f"uss-synth: removed {partial} (left by a killed run)" in rerun.stderr
    assert (
        f"uss-synth: warning: {out}: taking over the lock {tmp_path / '.seq.lock'}" in rerun.stderr
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    assert len(list((out / "rgb").glob("*.png"))) == 60 and (out / OUTPUT_MARKER).is_file()
    assert not (out / PARTIAL_MARKER).exists()
    # ... byte-identical to a render that was never interrupted
    clean = render_sequence(tmp_path / "clean", preset="walking_xyz", frames=60, size=(32, 24))
    assert _tree(out) == _tree(clean)


@pytest.mark.slow
def test_kill_9_while_overwriting_keeps_the_old_output(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    render_sequence(out, preset="walking_xyz", frames=4, size=(32, 24))
    before = _tree(out)
    _kill_while_rendering(_command(out, 60, "--overwrite"), out)
    assert _tree(out) == before  # replaced only after a complete render
    assert len(_partials(out)) == 1
    rerun = subprocess.run(_command(out, 6, "--overwrite"), capture_output=True, text=True,
                           timeout=300)  # fmt: skip
    assert rerun.returncode == 0, rerun.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    assert len(list((out / "rgb").glob("*.png"))) == 6


def _marked(folder: Path, pid: int, host: str | None = None) -> Path:
    folder.mkdir()
    (folder / "rgb").mkdir()
    (folder / "rgb" / "0.png").write_bytes(b"half")
    owner = {"pid": pid, "host": host or socket.gethostname(), "out": "x"}
    (folder / PARTIAL_MARKER).write_text(json.dumps(owner))
    return folder


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_only_marked_partials_of_gone_processes_are_removed(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        dead = _marked(tmp_path / ".seq.partial-dead", _dead_pid())
        old = _marked(tmp_path / ".seq.partial-x1-old", _dead_pid())  # an interrupted swap
        reused_pid = _marked(tmp_path / ".seq.partial-mypid", os.getpid())  # not ours now
        alive = _marked(tmp_path / ".seq.partial-alive", sleeper.pid)
        foreign = _marked(tmp_path / ".seq.partial-host", _dead_pid(), host="another-host")
        unmarked = tmp_path / ".seq.partial-unmarked"
        unmarked.mkdir()
        garbled = tmp_path / ".seq.partial-garbled"
        garbled.mkdir()
        (garbled / PARTIAL_MARKER).write_text("{not json")
        other_output = _marked(tmp_path / ".seq2.partial-dead", _dead_pid())
        assert stale_partials(out) == sorted([dead, old, reused_pid])
        render_sequence(out, preset="static_xyz", frames=2, size=(32, 24))
        left = sorted(p.name for p in tmp_path.iterdir())
        assert left == sorted(
            ["seq", alive.name, foreign.name, unmarked.name, garbled.name, other_output.name]
        )
        assert clean_stale_partials(out) == []
    finally:
        sleeper.kill()
        sleeper.wait()


def test_a_partial_in_progress_in_this_process_is_kept(tmp_path: Path) -> None:
    """The renderer's own partial folder (same pid, in progress) is never taken for stale."""
    from uss_slam.synthetic.output import staged_output

    out = tmp_path / "seq"
    with staged_output(out, overwrite=False) as tmp:
        assert (tmp / PARTIAL_MARKER).is_file()
        assert stale_partials(out) == []
    assert (out / OUTPUT_MARKER).is_file() and not (out / PARTIAL_MARKER).exists()

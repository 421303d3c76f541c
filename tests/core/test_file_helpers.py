"""The shared torch-free file helpers."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from uss_slam.core.errors import OutputInUseError
from uss_slam.core.files import file_sha256, folder_fingerprint, output_lock


def test_file_sha256_matches_hashlib_across_block_boundaries(tmp_path: Path) -> None:
    for size in (0, 1, (1 << 20) - 1, 1 << 20, (1 << 20) * 2 + 17):
        data = (bytes(range(251)) * (size // 251 + 2))[size % 7 : size % 7 + size]
        assert len(data) == size
        path = tmp_path / f"f{size}.bin"
        path.write_bytes(data)
        assert file_sha256(path) == hashlib.sha256(data).hexdigest()


def test_folder_fingerprint_sees_added_removed_and_rewritten_files(tmp_path: Path) -> None:
    seq = tmp_path / "seq"
    (seq / "rgb").mkdir(parents=True)
    (seq / "rgb" / "0.png").write_bytes(b"frame")
    (seq / "rgb.txt").write_text("0 rgb/0.png\n")
    first = folder_fingerprint(seq)
    assert folder_fingerprint(seq) == first  # stat only, stable
    (seq / ".uss-demo.json").write_text("{}")  # hidden files are not content
    (seq / "rgb" / ".tmp").write_text("x")
    assert folder_fingerprint(seq) == first
    stamp = (seq / "rgb" / "0.png").stat().st_mtime_ns
    (seq / "rgb" / "0.png").write_bytes(b"FRAME")  # same name and size, new content
    os.utime(seq / "rgb" / "0.png", ns=(stamp + 10**9, stamp + 10**9))
    rewritten = folder_fingerprint(seq)
    assert rewritten != first
    (seq / "rgb" / "1.png").write_bytes(b"frame")
    added = folder_fingerprint(seq)
    assert added != rewritten
    (seq / "rgb" / "1.png").unlink()
    assert folder_fingerprint(seq) == rewritten
    shutil.copytree(seq, tmp_path / "copy")  # copy2 keeps sizes and times: same content key
    assert folder_fingerprint(tmp_path / "copy") == rewritten


def test_files_module_does_not_import_torch() -> None:
    # uss-demo and slam_eval-side users import it; it must stay light.
    code = "import sys, uss_slam.core.files; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ------------------------------------------------------------------------------ output locks


def _hold(target: Path, *, fork_child: bool = False) -> subprocess.Popen:
    """A process holding ``target``'s lock until its stdin closes (``fork_child``: a forked
    child that shares the lock, as a pool worker does, is left sleeping after the holder is
    killed; it prints its pid)."""
    code = textwrap.dedent(f"""
        import os, sys, time
        from uss_slam.core.files import output_lock
        with output_lock(sys.argv[1]):
            if {fork_child}:
                child = os.fork()
                if child == 0:
                    time.sleep(60)
                    os._exit(0)
                print(child, flush=True)
            print("held", flush=True)
            sys.stdin.read()
    """)
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(target)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    return proc


def _in_use_line(target: Path, key: str | None = None) -> str:
    with pytest.raises(OutputInUseError) as info, output_lock(target, key):
        pass
    assert info.value.exit_code == 2
    return str(info.value)


def test_output_lock_keeps_a_second_process_out(tmp_path: Path) -> None:
    """The lock file ``.<name>.lock`` beside the output names the holder; a second locker
    gets one line with the key, the output and that pid; the lock file goes with the holder."""
    target = tmp_path / "run"
    holder = _hold(target)
    assert holder.stdout is not None and holder.stdout.readline() == "held\n"
    lock = tmp_path / ".run.lock"
    info = json.loads(lock.read_text())
    assert info["pid"] == holder.pid and info["host"] == socket.gethostname()
    line = _in_use_line(target, "out_dir")
    assert line == f"out_dir={target} is in use by pid {holder.pid} (started {info['started']})"
    assert not target.exists()  # the output itself is never created by its lock
    assert holder.stdin is not None
    holder.stdin.close()
    assert holder.wait(timeout=30) == 0
    assert list(tmp_path.iterdir()) == []
    with output_lock(target) as path:  # free again
        assert path == lock and lock.is_file()
    assert not lock.exists()


def test_output_lock_is_reentrant_within_a_process(tmp_path: Path) -> None:
    target = tmp_path / "exports" / "m.onnx"
    with output_lock(target) as outer:
        with output_lock(target) as inner:
            assert inner == outer == tmp_path / "exports" / ".m.onnx.lock"
        assert outer.is_file()  # still held by the outer block
    assert not outer.exists()


def test_ctrl_c_just_after_the_lock_file_is_made_leaves_no_lock_behind(
    tmp_path: Path, monkeypatch
) -> None:
    """A Ctrl-C arriving between the lock file's creation and the block that removes it waits
    for that block: the interrupt still stops the run, and no lock file is left beside it."""
    target = tmp_path / "out"
    real_open = os.open

    def open_then_ctrl_c(*args, **kwargs):
        fd = real_open(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        return fd

    monkeypatch.setattr(os, "open", open_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt), output_lock(target):
        pass  # the deferred Ctrl-C is raised as the lock is taken, inside its clean-up
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    with output_lock(target):  # free again, with no warning about an earlier holder
        pass


def test_a_lock_left_by_a_killed_process_is_taken_over_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """kill -9 of the holder: the kernel drops the lock, its file stays; the next locker takes
    it over and says whose it was."""
    target = tmp_path / "seq"
    holder = _hold(target)
    assert holder.stdout is not None and holder.stdout.readline() == "held\n"
    started = json.loads((tmp_path / ".seq.lock").read_text())["started"]
    holder.kill()
    holder.wait(timeout=30)
    assert (tmp_path / ".seq.lock").is_file()
    with caplog.at_level(logging.WARNING), output_lock(target, "--out"):
        assert json.loads((tmp_path / ".seq.lock").read_text())["pid"] == os.getpid()
    assert caplog.messages == [
        f"--out={target}: taking over the lock {tmp_path / '.seq.lock'} left by pid "
        f"{holder.pid} (started {started}), which ended without releasing it"
    ]
    assert not (tmp_path / ".seq.lock").exists()


def test_a_forked_worker_that_outlives_its_parent_keeps_the_lock(tmp_path: Path) -> None:
    """A child forked while the lock is held shares it: after kill -9 of the parent the output
    stays locked while the child runs (the line says so), and is free once it ends."""
    target = tmp_path / "demo"
    holder = _hold(target, fork_child=True)
    assert holder.stdout is not None
    child = int(holder.stdout.readline())
    assert holder.stdout.readline() == "held\n"
    try:
        holder.kill()
        holder.wait(timeout=30)
        line = _in_use_line(target)
        assert line.startswith(f"{target} is in use by a process that pid {holder.pid} (started ")
        assert line.endswith(", now ended) left running")
    finally:
        os.kill(child, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while True:  # the child is reaped by init, then its lock is released
        try:
            with output_lock(target):
                break
        except OutputInUseError:
            assert time.monotonic() < deadline
            time.sleep(0.05)


def test_one_output_spelled_two_ways_has_one_lock(tmp_path: Path, monkeypatch) -> None:
    """``../out/o`` from a sibling folder, the absolute path and a link to its folder name one
    lock: the lock is re-entrant for them in this process (a run found its own folder "in use
    by" itself when a stage locked it under another spelling)."""
    from uss_slam.core.files import lock_path, output_lock

    (tmp_path / "work").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "out")
    monkeypatch.chdir(tmp_path / "work")
    spellings = ["../out/o", tmp_path / "out" / "o", tmp_path / "link" / "o", "../work/../out/o"]
    assert {lock_path(s) for s in spellings} == {tmp_path / "out" / ".o.lock"}
    with output_lock("../out/o"), output_lock(tmp_path / "link" / "o", "out_dir"):
        pass


def test_a_failed_atomic_write_leaves_no_folder_it_made(tmp_path: Path) -> None:
    """The folders an atomic write made for its file are removed again when it fails (a full
    disk, an interrupt): a failed run leaves no empty output folder (uss-eval's --out did)."""
    from uss_slam.core.files import atomic_path

    (tmp_path / "kept").mkdir()
    with pytest.raises(OSError), atomic_path(tmp_path / "kept" / "new" / "deeper" / "f.json"):
        raise OSError("the write failed")
    assert [p.name for p in tmp_path.rglob("*")] == ["kept"]

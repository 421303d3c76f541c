"""The families of the fifth held-out set, at the shared layer: the shell's state a script starts in, a working folder deleted, a umask
that makes new folders unwritable, a file size limit (``ulimit -f``), stdout full or closed, an
image header declaring more pixels than any image may have, an interactive matplotlib backend,
and a training run's config edited by hand. Each is one line naming what to change."""

from __future__ import annotations

import errno
import io
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

from uss_slam.core import launch, stdout
from uss_slam.core.cli import print_output
from uss_slam.core.errors import DataFormatError, NoSpaceError, UssSlamError
from uss_slam.core.files import no_space_errno
from uss_slam.core.images import read_colour
from uss_slam.core.paths import PathError, input_file, output_file, output_folder


@pytest.fixture
def cwd_gone(tmp_path: Path):
    """The process's working folder deleted under it (another terminal's ``rm -r``)."""
    before = os.getcwd()
    gone = tmp_path / "gone"
    gone.mkdir()
    os.chdir(gone)
    gone.rmdir()
    try:
        yield tmp_path
    finally:
        os.chdir(before)


def test_a_relative_path_in_a_deleted_working_folder_is_one_line(cwd_gone: Path) -> None:
    with pytest.raises(PathError, match=r"^--out=v: a relative path, and the working folder no "):
        output_folder("v", "--out")
    with pytest.raises(PathError, match=r"^--plot=p.png: a relative path"):
        output_file("p.png", "--plot")
    assert input_file(__file__) == Path(__file__)  # an absolute path needs no working folder


def test_a_hydra_app_in_a_deleted_working_folder_is_one_line(cwd_gone: Path) -> None:
    assert launch.working_folder_line("uss-slam") == (
        "uss-slam: error: the working folder no longer exists (it was deleted); run from an "
        "existing folder"
    )
    assert launch.working_folder_line("uss-traj") is None  # its relative paths: the path layer


@pytest.fixture
def umask_0222():
    before = os.umask(0o222)
    try:
        yield
    finally:
        os.umask(before)


def test_a_umask_that_leaves_new_folders_unwritable_is_refused_before_any_work(
    tmp_path: Path, umask_0222
) -> None:
    with pytest.raises(PathError, match=r"the umask 0222 removes the owner's write permission"):
        output_folder(tmp_path / "new" / "v", "--out", create=False)
    with pytest.raises(PathError, match=r"^--out=.*/new/v.txt: a folder created now"):
        output_file(tmp_path / "new" / "v.txt", "--out")
    assert output_file(tmp_path / "v.txt", "--out") == tmp_path / "v.txt"  # its folder exists


def test_a_file_size_limit_is_handled_as_a_full_disk() -> None:
    """``ulimit -f``: Python ignores SIGXFSZ, a write past the limit fails with EFBIG."""
    error = OSError(errno.EFBIG, "File too large")
    assert no_space_errno(RuntimeError("not a write")) is None
    wrapped = RuntimeError("a library's")
    wrapped.__cause__ = error
    assert no_space_errno(wrapped) == errno.EFBIG
    assert str(NoSpaceError("/o/v.txt", errno.EFBIG)) == (
        "the file size limit is exceeded (ulimit -f) while writing /o/v.txt"
    )


class _Full(io.StringIO):
    def write(self, text: str) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")


def test_a_full_stdout_is_the_products_error_and_a_warning_for_the_rest(
    monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.setattr(sys, "stdout", _Full())
    stdout.guard()
    print("a progress note")  # kept, not raised
    with pytest.raises(UssSlamError, match=r"^stdout: cannot write the output \(No space left"):
        print_output("the numbers")
    print("another note")
    monkeypatch.setattr(os, "dup2", lambda *a: None)  # (the test's stdout has no descriptor)
    stdout.report_lost("uss-synth")
    assert capsys.readouterr().err.startswith("uss-synth: warning: stdout: cannot write to it (")
    assert stdout.lost() is None


class _ClosedPipe(io.StringIO):
    """Stdout whose reader is gone (``| head -1`` after its line)."""

    def write(self, text: str) -> int:
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    def fileno(self) -> int:
        raise io.UnsupportedOperation("fileno")


def test_a_closed_pipe_is_the_products_exit_and_one_warning_for_the_rest(
    monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``uss-eval ... | head -1``: its summary's print was a ``BrokenPipeError`` traceback after
    the work. A product (``uss-traj``'s numbers) exits with 1 without a word; anything else is
    kept and said once at the end, the run going on."""
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    stdout.guard()
    assert print_output("the numbers") == 1
    print("a summary beside the files")  # kept, not raised
    stdout.report_lost("uss-eval")
    assert capsys.readouterr().err.splitlines() == [
        "uss-eval: warning: stdout: its reader closed the pipe (| head?); the rest of what the "
        "script printed there is lost (its files are complete)"
    ]


def test_a_script_into_a_closed_pipe_finishes_its_work_with_one_warning(tmp_path: Path) -> None:
    """A console script whose stdout is a pipe closed before its last line (``uss-synth ... |
    head -c0``): its files are written, exit code 0, one warning (it was a traceback)."""
    reader, writer = os.pipe()
    os.close(reader)
    code = "import sys; from uss_slam.core.launch import uss_synth; uss_synth()"
    out = tmp_path / "voc"
    try:
        done = subprocess.run([sys.executable, "-c", code, "voc", "--images", "1", "--size",
                               "32x24", "--out", str(out), "--quiet"], stdout=writer,
                              stderr=subprocess.PIPE, text=True, timeout=300)  # fmt: skip
    finally:
        os.close(writer)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert [line for line in done.stderr.splitlines() if "uss-synth:" in line] == [
        "uss-synth: warning: stdout: its reader closed the pipe (| head?); the rest of what the "
        "script printed there is lost (its files are complete)"
    ]
    assert any(out.rglob("*.png"))


def test_a_read_only_home_gives_matplotlib_a_folder_of_its_own_without_a_word(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where matplotlib cannot write ``~/.config/matplotlib`` (a read-only home folder; here a
    file in the way, which root cannot write through either) it printed two lines of its own on
    import; the launcher gives it a temporary folder, and a writable one stays matplotlib's."""
    (tmp_path / "afile").write_text("")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MPL", "XDG_"))}
    env["XDG_CONFIG_HOME"] = str(tmp_path / "afile" / "config")
    code = ("from uss_slam.core import launch; launch.private_matplotlib_folder(); "
            "import matplotlib; matplotlib.get_cachedir(); print(matplotlib.get_configdir())")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert (done.returncode, done.stderr) == (0, ""), done.stderr
    assert "uss-slam-matplotlib-" in done.stdout
    assert not Path(done.stdout.strip()).exists()  # removed at the end
    monkeypatch.delenv("MPLCONFIGDIR", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    launch.private_matplotlib_folder()
    assert "MPLCONFIGDIR" not in os.environ


ORT_SCRIPT = """
import sys, types
from uss_slam.core import launch

def main():
    import onnxruntime  # noqa: F401
    return 0

module = types.ModuleType("ort_script")
module.main = main
sys.modules["ort_script"] = module
launch.SCRIPTS["uss-ort"] = "ort_script"
sys.exit(launch.launch("uss-ort"))
"""


def test_onnxruntime_writes_nothing_into_the_home_folder(tmp_path: Path) -> None:
    """onnxruntime wrote a device id under ``~/.cache/Microsoft/DeveloperTools`` (a file outside
    the outputs) and, in a read-only home folder, printed its own coloured warning on import."""
    home = tmp_path / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ORT_", "XDG_"))}
    env["HOME"] = str(home)
    done = subprocess.run([sys.executable, "-c", ORT_SCRIPT], env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert (done.returncode, done.stderr) == (0, ""), done.stderr
    assert list(home.rglob("*")) == []


def test_a_closed_stdout_is_the_products_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "stdout", None)
    with pytest.raises(UssSlamError, match=r"^stdout is closed"):
        print_output("the numbers")


def test_an_interactive_matplotlib_backend_is_not_the_scripts(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    monkeypatch.setattr(launch.importlib, "import_module", lambda name: _Main)
    monkeypatch.setattr(sys, "stdout", sys.stdout)  # the guard's wrapper is undone after
    assert launch.launch("uss-traj") == 0
    assert os.environ["MPLBACKEND"] == "Agg"


class _Main:
    @staticmethod
    def main() -> int:
        return 0


def _png_header(width: int, height: int) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    body = chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    return b"\x89PNG\r\n\x1a\n" + body


def test_an_image_header_past_the_pixel_limit_is_refused_before_decoding(tmp_path: Path) -> None:
    path = tmp_path / "bomb.png"
    path.write_bytes(_png_header(60000, 60000))
    with pytest.raises(DataFormatError, match=r"bomb.png: its header declares 60000x60000 pixels"):
        read_colour(path)


def test_torchs_allocation_failure_is_out_of_memory() -> None:
    error = RuntimeError(
        "[enforce fail at alloc_cpu.cpp:127] err == 0. DefaultCPUAllocator: can't allocate "
        "memory: you tried to allocate 480000000000 bytes. Error code 12"
    )
    assert launch.out_of_memory(error)
    assert not launch.out_of_memory(RuntimeError("shape mismatch"))


def test_a_path_the_terminals_encoding_cannot_hold_is_escaped(tmp_path: Path) -> None:
    """``PYTHONIOENCODING=ascii`` (or a Latin-1 terminal) and a non-ASCII output path: the
    script's lines on stdout and stderr escape the character (``r\\xe9``); it was a
    ``UnicodeEncodeError`` traceback after the work was done."""
    import subprocess

    script = Path(sys.executable).parent / "uss-synth"
    env = {**os.environ, "PYTHONIOENCODING": "ascii:strict"}
    out = tmp_path / "ré"
    args = ["voc", "--images", "1", "--size", "32x24", "--out", str(out)]
    done = subprocess.run([str(script), *args], capture_output=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert b"r\\xe9/VOCdevkit" in done.stdout and b"Traceback" not in done.stderr
    again = subprocess.run([str(script), *args], capture_output=True, env=env, timeout=120)
    assert again.returncode != 0  # (its earlier output: refused)
    assert again.stderr.decode("ascii").startswith(f"uss-synth: error: --out={tmp_path}/r\\xe9:")


def test_a_closed_stderr_keeps_the_lines_out_of_stdout(tmp_path: Path) -> None:
    """``2>&-``: Python's ``sys.stderr`` is None and ``print(..., file=None)`` writes to stdout,
    so the error line landed in the script's product (``uss-traj --json > r.json``). It goes
    nowhere; the exit code tells."""
    traj = Path(sys.executable).parent / "uss-traj"
    done = subprocess.run(
        [str(traj), "ate", str(tmp_path / "no.txt"), str(tmp_path / "no.txt")],
        capture_output=True,
        text=True,
        check=False,
        preexec_fn=lambda: os.close(2),
    )
    assert (done.returncode, done.stdout) == (1, "")

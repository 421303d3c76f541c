"""Small torch-free file helpers shared by every package: hashing, atomic writes (a temporary
sibling renamed into place: one file, or a set of files committed together), the check that
an output folder can be written, and the lock that keeps a second process out of an output
another one is writing. Every package writes its outputs through these.

A full disk (``ENOSPC``, or ``EDQUOT`` for an exhausted quota) while an output is written is a
:class:`~uss_slam.core.errors.NoSpaceError` naming the output's final path; its temporary file
is removed and the earlier file under that name stays as it was.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import os
import re
import socket
import threading
import time
import uuid
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import Any, BinaryIO

from uss_slam.core.errors import NO_SPACE_ERRNOS, NoSpaceError, OutputInUseError, UssSlamError

log = logging.getLogger(__name__)


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


TORCH_ZIP = b"PK\x03\x04"
"""How a ``torch.save`` file starts (a zip archive); the legacy format starts as a pickle."""


def saved_by_torch(path: str | PathLike[str]) -> bool:
    """Whether the file ``path`` starts as one of ``torch.load``'s two formats (a zip archive or
    a pickle), read from its first 4 bytes without importing torch: an ONNX model, an image or
    a text file given as weights is not. An unreadable file is the caller's to report."""
    with open(path, "rb") as file:
        head = file.read(4)
    return head == TORCH_ZIP or head.startswith(b"\x80")


def folder_fingerprint(folder: str | PathLike[str]) -> str:
    """Hex SHA-256 of every file under ``folder`` by relative path, size and modification time
    (nanoseconds), hidden names (``.*``) left out: a cache key that changes when a file is
    added, removed, replaced or rewritten, without reading the files (cheap for a sequence of
    thousands of frames)."""
    root = Path(folder)
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if any(part.startswith(".") for part in rel.parts) or not path.is_file():
            continue
        info = path.stat()
        digest.update(f"{rel.as_posix()}\0{info.st_size}\0{info.st_mtime_ns}\n".encode())
    return digest.hexdigest()


def content_key(folder: str | PathLike[str]) -> str:
    """A data folder as a cache key: ``<path>:<folder_fingerprint>``, so that files changed
    under the same names redo what reads them."""
    return f"{folder}:{folder_fingerprint(folder)}"


@contextmanager
def atomic_path(path: str | PathLike[str], prefix: str = ".") -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; it is renamed onto ``path`` only when the
    block ends normally and removed when it raises, so a reader never sees half a file and an
    interrupted write leaves ``path`` as it was. The temporary name is
    ``<prefix><name>.<random>.tmp`` (callers that clean up after killed runs match the prefix).
    """
    path = Path(path)
    made = [f for f in (path.parent, *path.parent.parents) if not os.path.lexists(f)]
    path.parent.mkdir(parents=True, exist_ok=True)
    done = False
    try:
        tmp = _create_sibling(path, prefix)
    except OSError as error:
        _remove_empty(made)
        _raise_if_no_space(error, path)
        raise
    try:
        yield tmp
        os.replace(tmp, path)
        done = True
    except Exception as error:
        _raise_if_no_space(error, path)
        raise
    finally:
        tmp.unlink(missing_ok=True)
        if not done:
            _remove_empty(made)


def _remove_empty(made: list[Path]) -> None:
    """Remove the folders a failed write made (deepest first) while they are empty: a failed
    run leaves no empty output folder behind."""
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            return


def stale_temporaries(path: str | PathLike[str], prefix: str = ".") -> list[Path]:
    """The temporary files of ``path`` that a killed writer left (kill -9, a power cut: no
    ``finally`` ran): :func:`atomic_path`'s and :class:`StagedFiles`'
    ``<prefix><name>.<random>.tmp`` beside it, and a scratch file staged beside such a file
    (``.<that name>.<suffix>.<random>.tmp``). Only the writer that holds the output's lock
    (:func:`output_lock`) may remove them: another process's writes are named the same."""
    path = Path(path)
    own = re.compile(rf"{re.escape(prefix + path.name)}\.[0-9a-f]{{12}}\.tmp")
    scratch = re.compile(rf"\.{own.pattern}\.[^/]+\.[0-9a-f]{{12}}\.tmp")
    try:
        names = [entry.name for entry in os.scandir(path.parent) if entry.is_file()]
    except OSError:  # the folder does not exist (yet): nothing was left
        return []
    return sorted(path.parent / n for n in names if own.fullmatch(n) or scratch.fullmatch(n))


def no_space_errno(error: BaseException | None) -> int | None:
    """``ENOSPC`` / ``EDQUOT`` when an ``OSError`` of a full disk is in ``error``'s cause chain
    (libraries wrap it: ``__cause__`` / ``__context__``), else None."""
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        if isinstance(error, OSError | NoSpaceError) and error.errno in NO_SPACE_ERRNOS:
            return int(error.errno)  # (a NoSpaceError that crossed a process has no cause)
        error = error.__cause__ or error.__context__
    return None


def _raise_if_no_space(error: BaseException, path: str | PathLike[str] | None) -> None:
    """Raise :class:`NoSpaceError` for ``path`` when ``error`` comes from a full disk (an error
    that already is one, from a nested write, goes on as it is)."""
    if isinstance(error, NoSpaceError):
        return
    code = no_space_errno(error)
    if code is not None:
        raise NoSpaceError(path, code) from error


def write_file(path: str | PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` in place (not atomically: for the files of a folder that
    appears under its name only when complete). A full disk removes the partial file and raises
    :class:`NoSpaceError` naming ``path``."""
    path = Path(path)
    try:
        with _open_new(path) as file:
            file.write(data)
    except OSError as error:
        if no_space_errno(error) is not None:
            path.unlink(missing_ok=True)
        _raise_if_no_space(error, path)
        raise


def _open_new(path: Path) -> BinaryIO:
    """``open(path, "wb")``: where :func:`write_file` starts a file."""
    return open(path, "wb")  # noqa: SIM115 (the caller closes it)


def _create_sibling(path: Path, prefix: str) -> Path:
    """Create an empty ``<prefix><name>.<random>.tmp`` next to ``path`` and return it.

    Created with mode 0666 for the kernel to apply the umask to, as a plain ``open()`` does
    (``tempfile.mkstemp`` would make every output 0600, readable by its owner only).
    """
    for _ in range(100):
        tmp = path.with_name(f"{prefix}{path.name}.{uuid.uuid4().hex[:12]}.tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"{path.parent}: no free temporary name for {path.name}")


def write_bytes_atomic(path: str | PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` through :func:`atomic_path` (creating the folder)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_path` (creating the folder)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json_atomic(path: str | PathLike[str], data: Any) -> None:
    """Indented JSON with a final newline, written atomically."""
    write_text_atomic(path, json.dumps(data, indent=2) + "\n")


class StagedFiles:
    """Files written under temporary names next to their final paths and renamed into place
    together by :meth:`commit`; files not committed are deleted when the ``with`` block ends.

    ``os.replace`` is atomic for one file; a set of files is committed in staging order right
    after each other, once everything was written and checked. Temporary names are
    ``.<name>.<random>.tmp``, as :func:`atomic_path`'s. A full disk while a staged file is
    written is a :class:`NoSpaceError` naming its final path (every staged file removed).
    """

    def __init__(self) -> None:
        self._staged: dict[Path, Path] = {}  # final path -> temporary path

    def __enter__(self) -> StagedFiles:
        return self

    def __exit__(self, kind: object, error: BaseException | None, tb: object) -> None:
        final = self._written_when(error)
        self.discard()
        if error is not None and isinstance(error, Exception):
            _raise_if_no_space(error, final)

    def _written_when(self, error: BaseException | None) -> Path | None:
        """The final path of the staged file an error happened on: the one its ``filename``
        names, else the one staged last (the file being written)."""
        if error is None or not self._staged:
            return None
        name = getattr(error, "filename", None)
        for final, tmp in self._staged.items():
            if name is not None and Path(name) == tmp:
                return final
        return next(reversed(self._staged))

    def path(self, final: Path) -> Path:
        """A fresh temporary file (created empty) in ``final``'s folder, to be written and
        renamed to ``final``."""
        if final in self._staged:
            raise ValueError(f"{final} is staged already")
        try:
            tmp = _create_sibling(final, ".")
        except OSError as error:
            _raise_if_no_space(error, final)
            raise
        self._staged[final] = tmp
        return tmp

    def write_json(self, final: Path, data: Mapping[str, Any]) -> None:
        """Stage indented JSON with a final newline for ``final``."""
        tmp = self.path(final)
        try:
            tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
        except OSError as error:
            _raise_if_no_space(error, final)
            raise

    def commit(self, remove: Iterable[Path] = ()) -> None:
        """Delete ``remove`` (files the new set makes stale), then rename every staged file to
        its final path."""
        for path in remove:
            if path.is_file():
                log.info("removing %s (left from an earlier run)", path)
                path.unlink()
        for final, tmp in list(self._staged.items()):
            os.replace(tmp, final)
            del self._staged[final]

    def discard(self) -> None:
        """Delete every staged file not committed."""
        for tmp in self._staged.values():
            tmp.unlink(missing_ok=True)
        self._staged.clear()


def check_writable(
    folder: str | PathLike[str], key: str | None = None, *, create: bool = True
) -> Path:
    """Create ``folder`` (with parents) and prove a file can be created in it; otherwise raise a
    one-line :class:`UssSlamError` naming the folder (as ``key=folder`` when ``key``, the option
    that chose it, is given): :func:`uss_slam.core.paths.output_folder`.

    ``create=False`` creates nothing (for a check long before the first output is written):
    the nearest existing folder on the way to ``folder`` must be a folder that can be written.
    """
    from uss_slam.core.paths import output_folder

    return output_folder(folder, key, create=create)


def check_name_lengths(path: str | PathLike[str], key: str | None = None) -> None:
    """Refuse (one line naming ``key=path``) a path the system cannot create: a name in it
    longer than ``NAME_MAX`` bytes (255 on Linux file systems) or the whole longer than
    ``PATH_MAX`` (4096); ``os.stat`` and ``mkdir`` would raise ``ENAMETOOLONG`` on it."""
    from uss_slam.core.paths import too_long, where

    reason = too_long(path)
    if reason:
        raise UssSlamError(f"{where(path, key)}: {reason}")


# ------------------------------------------------------------------------------ output locks

_held: dict[Path, int] = {}
"""Lock files this process holds -> how many :func:`output_lock` blocks hold each."""
_held_guard = threading.Lock()


def lock_path(target: str | PathLike[str]) -> Path:
    """The lock file of an output (a folder or a file): ``.<name>.lock`` beside it, so that the
    output's own content never includes it (an output folder that appears only when complete
    stays absent until then). For an existing folder whose parent cannot be written, ``.lock``
    inside it. The output is named by its real path (``..`` collapsed, links followed): one
    output spelled two ways (``../out/o`` and ``/data/out/o``, a link to it) has one lock."""
    target = Path(os.path.realpath(target))
    if target.is_dir() and not os.access(target.parent, os.W_OK):
        return target / ".lock"
    return target.parent / f".{target.name}.lock"


def _lock_info(fd: int) -> dict[str, Any]:
    """The holder a lock file names (``pid``, ``host``, ``started``); empty when unreadable."""
    try:
        raw = os.pread(fd, 4096, 0)
        info = json.loads(raw.decode()) if raw.strip() else {}
    except (OSError, ValueError):
        return {}
    return info if isinstance(info, dict) else {}


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _in_use_message(where: str, info: Mapping[str, Any]) -> str:
    pid, host, started = info.get("pid"), info.get("host"), info.get("started", "?")
    if not isinstance(pid, int):
        return f"{where} is in use by another process"
    if host != socket.gethostname():
        return f"{where} is in use by pid {pid} on {host} (started {started})"
    if not _pid_alive(pid):  # a child of that process, still writing, holds the lock
        return f"{where} is in use by a process that pid {pid} (started {started}, now ended) left running"
    return f"{where} is in use by pid {pid} (started {started})"


def lock_held(target: str | PathLike[str]) -> bool:
    """Whether a process (this one included) holds the lock of the output ``target`` now
    (:func:`output_lock`); False where there is no locking (not POSIX)."""
    try:
        import fcntl
    except ImportError:
        return False
    path = lock_path(target)
    with _held_guard:
        if path in _held:
            return True
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # no lock file: nobody holds it
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # releases the test lock
    return False


@contextmanager
def output_lock(target: str | PathLike[str], key: str | None = None) -> Iterator[Path]:
    """Hold the lock of the output ``target`` (a folder or a file) for the ``with`` block, so
    that two processes never write the same output at once; yields the lock file's path.

    The lock file (:func:`lock_path`) holds the holder's pid, host and start time; it is locked
    with ``flock``, which the kernel releases when the holder ends in any way (kill -9
    included), and removed when the block ends. While another process holds it,
    :class:`OutputInUseError` (exit code 2) says ``<target> is in use by pid N (started ...)``
    (``key=<target>`` when ``key``, the option that chose it, is given). A lock file left by a
    killed process is taken over with a warning naming it (:func:`uss_slam.core.cli.warning`). The lock is re-entrant within one
    process (a driver may lock an output its own stages lock again); it is shared with the
    processes this one forks, so that a worker still writing keeps it held.
    """
    if importlib.util.find_spec("fcntl") is None:  # not POSIX: no locking
        yield lock_path(target)
        return
    target = Path(target)
    where = str(target) if key is None else f"{key}={target}"
    path = lock_path(target)
    with _held_guard:
        if path in _held:
            _held[path] += 1
            reentrant = True
        else:
            reentrant = False
    if reentrant:
        try:
            yield path
        finally:
            with _held_guard:
                _held[path] -= 1
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_dir() or (path.exists() and not path.is_file()):
        kind = "a folder" if path.is_dir() else "not a regular file"
        raise UssSlamError(
            f"{path}: the lock file of {where} is {kind}; expected a file (or none): remove it"
        )
    # From the lock file's creation to the block that removes it, a Ctrl-C or SIGTERM waits:
    # one arriving in between would leave the file behind.
    from uss_slam.core.cli import interrupts_deferred, warning  # (core.cli imports this module)

    fd, mine = -1, None
    try:
        with interrupts_deferred():
            fd = _take_lock(path, where)
            left = _lock_info(
                fd
            )  # a released lock's file is removed: content means a killed holder
            if left:
                warning(
                    f"{where}: taking over the lock {path} left by pid {left.get('pid', '?')} "
                    f"(started {left.get('started', '?')}), which ended without releasing it"
                )
            me = {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "started": time.strftime("%Y-%m-%d %H:%M:%S"),
            }
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
            with _held_guard:
                _held[path] = 1
            mine = me["pid"]
        yield path
    finally:
        if mine is not None:
            with _held_guard:
                del _held[path]
            try:
                if os.getpid() == mine and os.path.samestat(os.fstat(fd), os.stat(path)):
                    path.unlink()  # before the lock is released: the next holder makes a new one
            except FileNotFoundError:
                pass
        if fd >= 0:
            os.close(fd)


def _take_lock(path: Path, where: str) -> int:
    """Open and ``flock`` the lock file ``path``; its descriptor. :class:`OutputInUseError`
    while another process holds it."""
    import fcntl

    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            info = _lock_info(fd)
            os.close(fd)
            raise OutputInUseError(_in_use_message(where, info)) from None
        try:  # the holder before us may have removed the file between our open and flock
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)


# ------------------------------------------------------------------------------ output owners

OUTPUT_MARKERS: dict[str, tuple[str, ...]] = {
    "uss-slam": ("run.json",),
    "uss-experiments": ("runs.csv", "tables.json"),
    "uss-demo": ("summary.json", "miou.json"),
    "uss-eval": ("eval.json", "compare.json"),
    "uss-train": ("checkpoints",),
    "uss-export": ("*.verify.json",),
}
"""What each console script leaves at the top of its output folder: the folder belongs to it
(a name, or a glob pattern: an export folder holds ``<name>.verify.json`` per model).
A Hydra app's record (``.hydra/hydra.yaml``, ``help.app_name``) names its app as well
(``uss-train``, ``uss-export``, ``uss-slam``, ``uss-experiments``)."""


def output_owner(folder: str | PathLike[str]) -> tuple[str, str] | None:
    """``(console script, what shows it)`` of the outputs ``folder`` holds (a marker of
    :data:`OUTPUT_MARKERS`, or the app a Hydra record names); None for a folder that does not
    exist or holds no tool's outputs."""
    path = Path(folder)
    if not path.is_dir():
        return None
    for prog, markers in OUTPUT_MARKERS.items():
        for marker in markers:
            found = next(path.glob(marker), None) if "*" in marker else path / marker
            if found is not None and found.exists():
                return prog, found.name
    record = path / ".hydra" / "hydra.yaml"
    if record.is_file():
        import yaml

        try:
            app = yaml.safe_load(record.read_text(encoding="utf-8"))["hydra"]["help"]["app_name"]
        except (OSError, ValueError, yaml.YAMLError, KeyError, TypeError):
            return None
        if isinstance(app, str) and app.startswith("uss-"):
            return app, ".hydra/hydra.yaml"
    return None


def check_output_owner(folder: str | PathLike[str], prog: str, key: str) -> None:
    """Refuse (one line naming ``key=folder``) an output folder that holds another console
    script's outputs: writing into it would overwrite or mix with them (``uss-demo --out`` on
    a ``uss-slam`` run would replace its ``report.md``)."""
    owner = output_owner(folder)
    if owner is not None and owner[0] != prog:
        raise UssSlamError(
            f"{key}={folder}: holds the outputs of {owner[0]} ({owner[1]}); expected a new "
            f"folder or an earlier {prog} output"
        )

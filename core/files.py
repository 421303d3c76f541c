"""Small torch-free file helpers shared by every package: hashing, atomic writes (a temporary
sibling renamed into place: one file, or a set of files committed together), and the check that
an output folder can be written. Every package writes its outputs through these."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import uuid
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import Any

from uss_slam.core.errors import UssSlamError

log = logging.getLogger(__name__)


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@contextmanager
def atomic_path(path: str | PathLike[str], prefix: str = ".") -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; it is renamed onto ``path`` only when the
    block ends normally and removed when it raises, so a reader never sees half a file and an
    interrupted write leaves ``path`` as it was. The temporary name is
    ``<prefix><name>.<random>.tmp`` (callers that clean up after killed runs match the prefix).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _create_sibling(path, prefix)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


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
        tmp.write_text(text)


def write_json_atomic(path: str | PathLike[str], data: Any) -> None:
    """Indented JSON with a final newline, written atomically."""
    write_text_atomic(path, json.dumps(data, indent=2) + "\n")


class StagedFiles:
    """Files written under temporary names next to their final paths and renamed into place
    together by :meth:`commit`; files not committed are deleted when the ``with`` block ends.

    ``os.replace`` is atomic for one file; a set of files is committed in staging order right
    after each other, once everything was written and checked. Temporary names are
    ``.<name>.<random>.tmp``, as :func:`atomic_path`'s.
    """

    def __init__(self) -> None:
        self._staged: dict[Path, Path] = {}  # final path -> temporary path

    def __enter__(self) -> StagedFiles:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.discard()

    def path(self, final: Path) -> Path:
        """A fresh temporary path (no file yet) in ``final``'s folder, to be renamed to
        ``final``."""
        if final in self._staged:
            raise ValueError(f"{final} is staged already")
        tmp = final.with_name(f".{final.name}.{uuid.uuid4().hex[:12]}.tmp")
        self._staged[final] = tmp
        return tmp

    def write_json(self, final: Path, data: Mapping[str, Any]) -> None:
        """Stage indented JSON with a final newline for ``final``."""
        self.path(final).write_text(json.dumps(data, indent=2) + "\n")

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
    that chose it, is given).

    ``create=False`` creates nothing (for a check long before the first output is written):
    the nearest existing folder on the way to ``folder`` must be a folder that can be written.
    """
    path = Path(folder)
    where = str(path) if key is None else f"{key}={path}"
    if path.exists() and not path.is_dir():
        raise UssSlamError(f"{where}: output folder is a file, not a folder")
    probe = path  # the nearest existing folder on the way to it
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise UssSlamError(f"{where}: cannot create the output folder ({probe} is a file)")
    try:
        if create:
            path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path if create else probe, prefix=".uss-slam-probe."):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise UssSlamError(f"{where}: cannot write to the output folder ({reason})") from None
    return path

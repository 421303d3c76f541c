"""The project's exception base and the errors for bad input files, a full disk and an output
folder another process is using.

Pure Python: every layer (the SLAM runtime included, which never imports torch) may import it.
"""

from __future__ import annotations

import errno
import os
from os import PathLike

from uss_slam.core.output_keys import key_of

_CONTROL = {c: repr(chr(c))[1:-1] for c in (*range(0x20), 0x7F)}


def shown(path: str | PathLike[str]) -> str:
    """``path`` as an error line names it: a control character (a newline, a carriage return, a
    terminal's escape, which a file name may hold) written as Python writes it (``\\n``,
    ``\\x1b``), so that the line stays one line and prints nothing it does not say."""
    return str(path).translate(_CONTROL)


class UssSlamError(Exception):
    """Base of every error this project raises on purpose (bad input, bad config, failed check).

    Console scripts turn it into one line on stderr and the exit code :attr:`exit_code`.
    """

    exit_code = 1
    """The exit code of a console script stopped by this error."""


class DataFormatError(UssSlamError, ValueError):
    """A file does not hold what it should.

    The message names the file, the line (1-based) when there is one, and what was expected.
    """

    def __init__(self, path: str | PathLike[str], message: str, line: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        self.detail = message
        where = shown(self.path) if line is None else f"{shown(self.path)}:{line}"
        super().__init__(f"{where}: {message}")

    def __reduce__(self) -> tuple[object, ...]:
        # rebuilt from its fields in another process (a worker's error): not from the message
        return (type(self), (self.path, self.detail, self.line))


NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
"""``errno`` values of a full file system (ENOSPC), an exhausted disk quota (EDQUOT) or a file
past the process's size limit (EFBIG: ``ulimit -f``; Python ignores the SIGXFSZ that would
otherwise kill it): an output that cannot be written whole, handled alike."""


class NoSpaceError(UssSlamError):
    """An output could not be written: the file system is full (or the user's quota is used).

    ``path`` is the output that was being written (its final name; the temporary file it was
    written to is already removed), ``errno`` ENOSPC, EDQUOT or EFBIG. The message starts with
    the key or flag that set the output holding ``path`` when the path layer checked one
    (:mod:`uss_slam.core.output_keys`): ``--out=/o: no space left on device while writing
    /o/a.png``.
    """

    def __init__(self, path: str | PathLike[str] | None, code: int = errno.ENOSPC) -> None:
        self.path = None if path is None else str(path)
        self.errno = code
        why = "no space left on device"
        if code == errno.EDQUOT:
            why += " (disk quota exceeded)"
        elif code == errno.EFBIG:
            why = "the file size limit is exceeded (ulimit -f)"
        named = None if path is None else key_of(path)  # the key or flag that set its output
        written = shown(self.path or "an output file")
        if named is None:
            super().__init__(f"{why} while writing {written}")
        elif os.path.abspath(named[1]) == os.path.abspath(self.path or ""):
            super().__init__(f"{named[0]}={shown(named[1])}: {why}")
        else:
            super().__init__(f"{named[0]}={shown(named[1])}: {why} while writing {written}")

    def __reduce__(self) -> tuple[object, ...]:
        # rebuilt from its fields in another process (a rendering worker's full disk), not
        # from the message, which would name it twice
        return (type(self), (self.path, self.errno))


class OutputInUseError(UssSlamError):
    """An output (folder or file) is being written by another running process: the second
    process stops before it writes anything (exit code 2)."""

    exit_code = 2

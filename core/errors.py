"""The project's exception base and the error for bad input files.

Pure Python: every layer (the SLAM runtime included, which never imports torch) may import it.
"""

from __future__ import annotations

from os import PathLike


class UssSlamError(Exception):
    """Base of every error this project raises on purpose (bad input, bad config, failed check).

    Console scripts turn it into one line on stderr and a non-zero exit code.
    """


class DataFormatError(UssSlamError, ValueError):
    """A file does not hold what it should.

    The message names the file, the line (1-based) when there is one, and what was expected.
    """

    def __init__(self, path: str | PathLike[str], message: str, line: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        self.detail = message
        where = self.path if line is None else f"{self.path}:{line}"
        super().__init__(f"{where}: {message}")

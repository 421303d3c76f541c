"""Which key or flag set each output path of this run, so that an error met while writing any
file under it names the setting the user can change (``--out=/data/s: the file size limit is
exceeded (ulimit -f) while writing /data/s/rgb/000.png``), not only a file the user never
named. The path layer (:mod:`uss_slam.core.paths`) records every output it checks with its
key; :class:`~uss_slam.core.errors.NoSpaceError` looks the key up.

Pure Python (floor 0): every layer may import it.
"""

from __future__ import annotations

import os
from os import PathLike

_keys: dict[str, tuple[str, str]] = {}
"""The absolute (and resolved) spelling of each checked output -> (its key, as given)."""


def _spellings(path: str | PathLike[str]) -> set[str]:
    """``path`` made absolute, as given and with its links resolved (empty when the working
    folder is gone and ``path`` is relative: it names nothing)."""
    try:
        return {os.path.abspath(path), os.path.realpath(path)}
    except OSError:
        return set()


def record(path: str | PathLike[str], key: str | None) -> None:
    """Remember that ``key`` set the output ``path`` (a folder or a file); a file checked
    inside a folder recorded for the same key (``out_dir``'s model file) is that folder's."""
    if key is None or (key_of(path) or ("",))[0] == key:
        return
    for spelling in _spellings(path):
        _keys[spelling] = (key, str(path))


def key_of(path: str | PathLike[str]) -> tuple[str, str] | None:
    """``(key, output as given)`` of the recorded output that is ``path`` or holds it (the
    nearest one), else None."""
    best: tuple[int, tuple[str, str]] | None = None
    for spelling in _spellings(path):
        for output, named in _keys.items():
            inside = spelling == output or spelling.startswith(output.rstrip(os.sep) + os.sep)
            if inside and (best is None or len(output) > best[0]):
                best = (len(output), named)
    return None if best is None else best[1]

"""Writing outputs safely: argument checks, all-or-nothing output folders, fixed encoder settings.

An output folder is rendered into a hidden sibling ``.<name>.partial-<random>`` that carries a
:data:`PARTIAL_MARKER` (the rendering process's id and host) and is renamed to ``<name>`` only
when complete; every complete output carries an :data:`OUTPUT_MARKER`. A process killed while
rendering leaves its partial folder behind: the next render of the same output removes it, and
only it (a sibling of that name pattern whose marker names a process of this host that is gone).
Overwriting is refused for a folder that is not a ``uss-synth`` output.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import tempfile
from collections.abc import Iterator
from os import PathLike
from pathlib import Path

import cv2
import numpy as np
import yaml

from uss_slam.core.errors import NoSpaceError, UssSlamError
from uss_slam.core.files import no_space_errno, output_lock, write_file, write_text_atomic

PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]
JPEG_PARAMS = [cv2.IMWRITE_JPEG_QUALITY, 90]
PARTIAL_MARKER = ".uss-synth-partial"
"""File in a folder being rendered: JSON ``{"pid", "host", "out"}`` of the rendering process."""
OUTPUT_MARKER = ".uss-synth"
"""File in every complete output folder (constant content: outputs stay byte-identical)."""
OUTPUT_MARKER_TEXT = "A uss-synth output: uss-synth --overwrite may replace this folder.\n"


class SynthArgumentError(UssSlamError, ValueError):
    """A bad argument to the synthetic-world writers (unknown preset, bad size, ...)."""


class OutputExistsError(UssSlamError, FileExistsError):
    """The output folder exists and is not empty, and overwriting was not asked for."""


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise SynthArgumentError(f"size must be WIDTHxHEIGHT like 640x480, got {text!r}")
    return check_size((int(parts[0]), int(parts[1])))


def check_size(size: tuple[int, int]) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise SynthArgumentError(f"size must be (width, height), got {size!r}") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise SynthArgumentError(f"size must be between 16x16 and 4096x4096, got {w}x{h}")
    return w, h


def write_png(path: Path, image: np.ndarray) -> None:
    """PNG with fixed compression (deterministic bytes); ``image`` RGB (H, W, 3) or one channel.

    Encoded in memory and written by Python (the bytes ``cv2.imwrite`` would write), so that a
    failed write says why (a full disk: :class:`~uss_slam.core.errors.NoSpaceError`)."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".png", image, PNG_PARAMS)
    if not ok:
        raise UssSlamError(f"{path}: could not encode PNG")
    write_file(path, data.tobytes())


def write_jpeg(path: Path, rgb: np.ndarray) -> None:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), JPEG_PARAMS)
    if not ok:
        raise UssSlamError(f"{path}: could not encode JPEG")
    write_file(path, data.tobytes())


def is_synth_output(folder: Path) -> bool:
    """True when ``folder`` was written by ``uss-synth``: it has the :data:`OUTPUT_MARKER`, or
    (outputs of earlier versions) a ``synthetic.yaml`` / ``demo.yaml`` naming uss-synth as its
    generator."""
    if (folder / OUTPUT_MARKER).is_file():
        return True
    for name in ("synthetic.yaml", "demo.yaml"):
        try:
            meta = yaml.safe_load((folder / name).read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError):
            continue
        if isinstance(meta, dict) and str(meta.get("generator", "")).startswith("uss-synth"):
            return True
    return False


def check_output(out_dir: str | PathLike[str], overwrite: bool, key: str = "--out") -> Path:
    """Refuse an existing non-empty ``out_dir`` unless ``overwrite``, and even then unless it is
    a ``uss-synth`` output (:func:`is_synth_output`); also refuse a file there. The line names
    ``key=<out_dir>`` (the path layer's form)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{key}={out}: is a file; expected a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise OutputExistsError(
                f"{key}={out}: the folder exists and is not empty; expected a new or empty "
                "folder (or --overwrite to replace an earlier uss-synth output)"
            )
        if not is_synth_output(out):
            raise OutputExistsError(
                f"{key}={out}: not a uss-synth output (no {OUTPUT_MARKER} or synthetic.yaml in "
                "it); refusing to overwrite it"
            )
    return out


_ACTIVE: set[Path] = set()
"""Partial folders this process is writing now (its own pid is never a sign of a dead owner)."""


def _owner_gone(folder: Path) -> bool:
    """True when ``folder``'s partial marker names a process of this host that no longer runs."""
    try:
        info = json.loads((folder / PARTIAL_MARKER).read_text(encoding="utf-8"))
        pid, host = int(info["pid"]), str(info["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return False  # no marker, or not ours to judge
    if host != socket.gethostname() or folder.absolute() in _ACTIVE:
        return False
    if pid == os.getpid():
        return True  # this process is not writing it: an earlier process had the same pid
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another user's
        return False
    return False


def stale_partials(out_dir: str | PathLike[str]) -> list[Path]:
    """Partial folders of ``out_dir`` left by killed ``uss-synth`` processes (see the module doc)."""
    out = Path(out_dir).absolute()
    if not out.parent.is_dir():
        return []
    prefix = f".{out.name}.partial-"
    return sorted(
        p
        for p in out.parent.iterdir()
        if p.name.startswith(prefix) and p.is_dir() and _owner_gone(p)
    )


def clean_stale_partials(out_dir: str | PathLike[str]) -> list[Path]:
    """Remove :func:`stale_partials` of ``out_dir``; returns what was removed."""
    removed = stale_partials(out_dir)
    for folder in removed:
        shutil.rmtree(folder, ignore_errors=True)
    return removed


@contextlib.contextmanager
def staged_output(out_dir: str | PathLike[str], overwrite: bool) -> Iterator[Path]:
    """Yield a temporary sibling folder to write into; move it to ``out_dir`` only on success.

    On any error the temporary folder is removed and ``out_dir`` is untouched (a killed process
    leaves it, marked: the next call for the same ``out_dir`` removes it); a full disk is a
    :class:`~uss_slam.core.errors.NoSpaceError` naming ``out_dir``. With ``overwrite`` an
    existing ``out_dir`` (a uss-synth output) is replaced only after the new content is complete.
    ``out_dir`` is locked meanwhile (:func:`~uss_slam.core.files.output_lock`): a second process
    rendering it stops with :class:`~uss_slam.core.errors.OutputInUseError`.
    """
    out = check_output(out_dir, overwrite).absolute()
    if out.is_symlink() and out.is_dir():  # a link to a folder: written where it points, as
        out = Path(os.path.realpath(out))  # the other scripts write through it (not replaced)
    out.parent.mkdir(parents=True, exist_ok=True)
    with output_lock(out):
        check_output(out, overwrite)  # again: another process may have finished it meanwhile
        clean_stale_partials(out)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
        tmp.chmod(0o755)  # mkdtemp makes it private; the result is an ordinary folder
        _ACTIVE.add(tmp)
        try:
            owner = {"pid": os.getpid(), "host": socket.gethostname(), "out": str(out)}
            write_text_atomic(tmp / PARTIAL_MARKER, json.dumps(owner) + "\n")
            yield tmp
            write_text_atomic(tmp / OUTPUT_MARKER, OUTPUT_MARKER_TEXT)
            (tmp / PARTIAL_MARKER).unlink()
        except BaseException as error:
            shutil.rmtree(tmp, ignore_errors=True)
            code = no_space_errno(error)  # also behind a NoSpaceError naming a file in tmp
            if code is not None:  # named by the output: the file being written is gone
                raise NoSpaceError(out, code) from error
            raise
        finally:
            _ACTIVE.discard(tmp)
        _replace(tmp, out)


def _replace(tmp: Path, out: Path) -> None:
    """Move the complete folder ``tmp`` to ``out``, replacing an earlier ``out``."""
    old = None
    if out.exists():
        # a name of the partial pattern: if killed while it is deleted, the next call removes it
        old = tmp.with_name(f"{tmp.name}-old")
        out.rename(old)
    tmp.rename(out)
    if old is not None:
        owner = {"pid": os.getpid(), "host": socket.gethostname(), "out": str(out)}
        write_text_atomic(old / PARTIAL_MARKER, json.dumps(owner) + "\n")
        shutil.rmtree(old, ignore_errors=True)

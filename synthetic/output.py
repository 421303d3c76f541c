"""Writing outputs safely: argument checks, all-or-nothing output folders, fixed encoder settings."""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator
from os import PathLike
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.errors import UssSlamError

PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]
JPEG_PARAMS = [cv2.IMWRITE_JPEG_QUALITY, 90]


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
    """PNG with fixed compression (deterministic bytes); ``image`` RGB (H, W, 3) or one channel."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), image, PNG_PARAMS):
        raise UssSlamError(f"{path}: could not write PNG")


def write_jpeg(path: Path, rgb: np.ndarray) -> None:
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), JPEG_PARAMS):
        raise UssSlamError(f"{path}: could not write JPEG")


def check_output(out_dir: str | PathLike[str], overwrite: bool) -> Path:
    """Refuse an existing non-empty ``out_dir`` unless ``overwrite``; also refuse a file there."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutputExistsError(f"{out}: folder exists and is not empty (use overwrite)")
    return out


@contextlib.contextmanager
def staged_output(out_dir: str | PathLike[str], overwrite: bool) -> Iterator[Path]:
    """Yield a temporary sibling folder to write into; move it to ``out_dir`` only on success.

    On any error the temporary folder is removed and ``out_dir`` is untouched. With
    ``overwrite`` an existing ``out_dir`` is replaced only after the new content is complete.
    """
    out = check_output(out_dir, overwrite).absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; the result is an ordinary folder
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{tmp.name.rsplit('-', 1)[-1]}"
        out.rename(old)
    tmp.rename(out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)

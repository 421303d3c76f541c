"""The files an export writes, and how they reach their final names.

``<name>.onnx`` comes with ``<name>.verify.json`` (and, with INT8, ``<name>.int8.onnx``); a
failed verification writes ``<name>.verify.failed.json`` instead. Every file is written under a
temporary name in its final folder (so the rename is atomic on one file system) and renamed into
place only when all files of the export are complete and verified (:class:`StagedFiles`).
"""

from __future__ import annotations

import json
import logging
import os
import uuid
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uss_slam.core.errors import UssSlamError
from uss_slam.core.onnx_contract import SegmenterMetadata

log = logging.getLogger(__name__)

VERIFY_SUFFIX = ".verify.json"
FAILED_SUFFIX = ".verify.failed.json"
INT8_SUFFIX = ".int8.onnx"


def sidecar(out: Path, suffix: str) -> Path:
    """``exports/x.onnx`` -> ``exports/x<suffix>`` (e.g. ``.verify.json``)."""
    return out.with_name(out.name.removesuffix(".onnx") + suffix)


@dataclass(frozen=True)
class ExportResult:
    """What :func:`~uss_slam.export.onnx.export_checkpoint` /
    :func:`~uss_slam.export.onnx.export_segmenter` wrote."""

    path: Path
    """The verified ONNX model."""
    verify_path: Path
    """``<name>.verify.json`` next to it."""
    verify: dict[str, Any]
    """The content of ``verify_path``."""
    metadata: SegmenterMetadata
    int8_path: Path | None = None
    """``<name>.int8.onnx`` when INT8 was requested (its figures are in ``verify["int8"]``)."""


def check_output_path(out: Path) -> None:
    """Refuse an output path that cannot become a model file (before any work is done)."""
    if out.suffix != ".onnx":
        raise UssSlamError(f"out must end in .onnx, got {out}")
    if out.is_dir():
        raise UssSlamError(f"out {out} is a folder; expected a file name ending in .onnx")


class StagedFiles:
    """Files written under temporary names next to their final paths and renamed into place
    together by :meth:`commit`; files not committed are deleted when the ``with`` block ends.

    ``os.replace`` is atomic for one file; a set of files is committed in staging order right
    after each other, once everything was written and checked.
    """

    def __init__(self) -> None:
        self._staged: dict[Path, Path] = {}  # final path -> temporary path

    def __enter__(self) -> StagedFiles:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.discard()

    def path(self, final: Path) -> Path:
        """A fresh temporary path in ``final``'s folder, to be renamed to ``final``."""
        if final in self._staged:
            raise ValueError(f"{final} is staged already")
        tmp = final.with_name(f".{final.name}.{uuid.uuid4().hex[:12]}.tmp")
        self._staged[final] = tmp
        return tmp

    def write_json(self, final: Path, data: Mapping[str, Any]) -> None:
        self.path(final).write_text(json.dumps(data, indent=2) + "\n")

    def commit(self, remove: Iterable[Path] = ()) -> None:
        """Delete ``remove`` (files the new export makes stale), then rename every staged file
        to its final path."""
        for path in remove:
            if path.is_file():
                log.info("removing %s (left from an earlier export)", path)
                path.unlink()
        for final, tmp in list(self._staged.items()):
            os.replace(tmp, final)
            del self._staged[final]

    def discard(self) -> None:
        for tmp in self._staged.values():
            tmp.unlink(missing_ok=True)
        self._staged.clear()


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write one JSON file atomically."""
    with StagedFiles() as staged:
        staged.write_json(path, data)
        staged.commit()

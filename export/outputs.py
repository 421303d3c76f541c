"""The files an export writes, and how they reach their final names.

``<name>.onnx`` comes with ``<name>.verify.json`` (and, with INT8, ``<name>.int8.onnx``); a
failed verification writes ``<name>.verify.failed.json`` instead. Every file is written under a
temporary name in its final folder (so the rename is atomic on one file system) and renamed into
place only when all files of the export are complete and verified
(:class:`uss_slam.core.files.StagedFiles`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uss_slam.core.errors import UssSlamError
from uss_slam.core.onnx_contract import SegmenterMetadata

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

"""``runs.csv``: one row per job of the experiment grid (its columns, written and read back
with numbers as int / float and empty cells as None)."""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import DataFormatError

from ..grid import TARGET_LABEL_USES

RATES = ("FPR", "FNR", "recall", "precision", "PWC")
ATE_KEYS = ("ate_rmse", "ate_mean", "ate_median", "ate_std")
REPEAT_COLUMNS = ("ate_runs", "ate_rmse_min", "ate_rmse_max")
"""A SLAM job's repeated runs (``slam.repeats``, ORB-SLAM3's): how many gave an ATE, and the
smallest and largest ATE RMSE among them (``ate_rmse`` is the median run's)."""
COLUMNS: tuple[str, ...] = (
    "kind",
    "id",
    "status",
    "reason",
    "method",
    "n_layers",
    "loss",
    "config",
    "target_labels",
    "init",
    "batchnorm",
    "seed",
    "system",
    "sequence",
    "variant",
    "val_mIoU",
    "mIoU",
    *(f"IoU_{c}" for c in CLASS_NAMES),
    *(f"person_{r}" for r in RATES),
    *ATE_KEYS,
    *REPEAT_COLUMNS,
    "tracked_fraction",
    "fps",
    "segmentation_ms",
    "crf_ms",
    "total_ms",
    "crf",
    "seconds",
    "folder",
)
"""The columns of ``runs.csv``, in order. ``target_labels``: what of the row's model was chosen
with target labels (:data:`~uss_slam.pipelines.experiments.grid.TARGET_LABEL_USES`, ``;``
between them; empty = nothing; a runs.csv from before the column reads as empty, and the tables
still mark the oracle and the checkpoint policy's rows). ``init``: the seed of the pretrained
init a training started from (empty: from scratch or a given file); ``batchnorm``: its
``model.net.batchnorm`` when the grid sets one (``grid.batchnorm``)."""
TIMING_COLUMNS = {
    "segmentation_ms": "segmentation",
    "crf_ms": "segmentation.crf",
    "total_ms": "total",
}
"""``runs.csv`` column -> key of a SLAM run's ``timing_ms`` (mean wall ms per processed frame;
``segmentation`` includes the CRF's ``segmentation.crf``)."""
INT_COLUMNS = ("n_layers", "init", "seed", "crf", "ate_runs")
TEXT_COLUMNS = (
    "kind",
    "id",
    "status",
    "reason",
    "method",
    "loss",
    "config",
    "target_labels",
    "batchnorm",
    "system",
    "sequence",
    "variant",
    "folder",
)
STATUSES = ("ok", "failed", "blocked", "missing")
ALL_SEQUENCES = "all"
"""``sequence`` of a segeval row pooled over every evaluation sequence."""
SOURCE_VAL = "source_val"
"""``sequence`` of a segeval row on the source validation split (T0's in-domain column)."""


def write_runs(path: Path, rows: Iterable[Mapping[str, Any]]) -> None:
    """``runs.csv`` with :data:`COLUMNS` (empty cell = no value)."""
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="raise")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if row.get(k) is None else row[k] for k in COLUMNS})
    tmp.replace(path)


def read_runs(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``runs.csv`` with numbers as int / float and empty cells as None."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise DataFormatError(path, f"cannot read runs table ({error.strerror})") from None
    reader = csv.DictReader(text.splitlines())
    missing = [c for c in ("kind", "id", "status") if c not in (reader.fieldnames or [])]
    if missing:
        raise DataFormatError(path, f"missing column(s) {', '.join(missing)}", line=1)
    rows = []
    for line, raw in enumerate(reader, start=2):
        row: dict[str, Any] = {}
        for key, value in raw.items():
            if key is None:
                raise DataFormatError(path, "more cells than columns", line=line)
            if value is None or value == "":
                row[key] = None
            elif key in TEXT_COLUMNS:
                row[key] = value
            else:
                try:
                    row[key] = int(value) if key in INT_COLUMNS else float(value)
                except ValueError:
                    raise DataFormatError(
                        path, f"column {key}: expected a number, got {value!r}", line=line
                    ) from None
        uses = row["target_labels"].split(";") if row.get("target_labels") else []
        unknown = [u for u in uses if u not in TARGET_LABEL_USES]
        if unknown:
            raise DataFormatError(
                path,
                f"column target_labels: expected {'; '.join(TARGET_LABEL_USES)} separated by ';', "
                f"got {unknown[0]!r}",
                line=line,
            )
        if row.get("status") not in STATUSES:
            raise DataFormatError(
                path,
                f"column status: expected one of {', '.join(STATUSES)}, got {row.get('status')!r}",
                line=line,
            )
        rows.append(row)
    return rows

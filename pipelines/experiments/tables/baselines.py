"""Baselines without a trained segmenter: no filter, geometry alone, ground-truth masks."""

from __future__ import annotations

from typing import Any

from uss_slam.slam_eval.variants import model_free

from ..grid import VARIANTS
from .layout import Layout, slam_rows
from .markdown import md_table
from .stats import stat

BASELINES = model_free(VARIANTS)
"""The variants without a trained segmenter (``configs/variants.yaml``: none, geometry, oracle)."""


def table_baselines(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    data: list[dict[str, Any]] = []
    lines: list[str] = []
    shown = [v for v in BASELINES if v in layout.variants]
    if not shown:
        return data, []
    for system in layout.systems:
        body = []
        for sequence in layout.sequences:
            cells = [sequence]
            for variant in shown:
                s = stat(slam_rows(rows, system, sequence, variant), "ate_rmse")
                cells.append(s.text(4))
                data.append(
                    {"system": system, "sequence": sequence, "variant": variant, **s.as_json()}
                )
            body.append(cells)
        lines += [
            f"### Baselines: ATE RMSE [m] without a trained segmenter ({system})",
            "",
            *md_table(["sequence", *(VARIANTS[v].label for v in shown)], body),
            "",
        ]
    return data, lines

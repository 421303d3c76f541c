"""Every table at once: ``tables.json`` and ``tables.md`` (with the plots)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from uss_slam.core.files import write_text_atomic

from .baselines import table_baselines
from .crf import table_crf
from .failures import table_failures
from .layout import Layout, layout_from_rows
from .plots import write_plots
from .ratio import table_ratio
from .t0 import table_t0
from .t1 import table_t1
from .t2 import table_methods, table_t2
from .t3 import table_t3
from .timing import table_timing


def compute(
    rows: Sequence[Mapping[str, Any]],
    n_layers: int | None,
    layout: Layout | None = None,
    policy: str = "last",
) -> tuple[dict[str, Any], str]:
    """Every table: ``(tables.json content, tables.md text)``; ``policy``: the trainings'
    checkpoint policy (``train.checkpoint``: the tables mark † the rows it selected with target
    labels, as they mark the rows whose ``target_labels`` column says so)."""
    layout = layout or layout_from_rows(rows, n_layers, policy)
    t0, t0_md = table_t0(rows, layout, policy)
    t1, t1_md = table_t1(rows, layout)
    t2, t2_md = table_t2(rows, layout)
    methods, methods_md = table_methods(rows, layout)
    t2["by_method"] = methods
    t3, t3_md = table_t3(rows, layout)
    crf, crf_md = table_crf(rows, layout)
    base, base_md = table_baselines(rows, layout)
    ratio, paired, ratio_md = table_ratio(rows, layout)
    timing, timing_md = table_timing(rows, layout)
    failures, failures_md = table_failures(rows)
    data = {
        "layout": {
            "configs": list(layout.configs),
            "sequences": list(layout.sequences),
            "systems": list(layout.systems),
            "variants": list(layout.variants),
            "source_only": layout.source_only,
            "adapted": list(layout.adapted),
            "methods": list(layout.methods),
            "crf_configs": list(layout.crf_configs),
            "adabn": list(layout.adabn),
            "oracle": layout.oracle,
            "n_layers": n_layers,
            "target_labels": {c: list(u) for c, u in layout.target_labels.items() if u},
        },
        "T0": t0,
        "T1": t1,
        "T2": t2,
        "T3": t3,
        "crf": crf,
        "baselines": base,
        "downstream_ratio": ratio,
        "downstream_ratio_paired": paired,
        "timing": timing,
        "failures": failures,
    }
    text = "\n".join(
        [
            *t0_md,
            *t1_md,
            *t2_md,
            *methods_md,
            *t3_md,
            *crf_md,
            *base_md,
            *ratio_md,
            *timing_md,
            *failures_md,
        ]
    )
    return data, text


def write_tables(
    out: Path,
    rows: Sequence[Mapping[str, Any]],
    n_layers: int | None,
    header: Sequence[str] = (),
    layout: Layout | None = None,
    plots: bool = True,
    policy: str = "last",
) -> dict[str, Any]:
    """``tables.md``, ``tables.json`` and the plots (under ``plots/``) in ``out``."""
    layout = layout or layout_from_rows(rows, n_layers, policy)
    data, text = compute(rows, n_layers, layout, policy)
    images = write_plots(out / "plots", rows, layout) if plots else []
    md = [*header, text]
    if images:
        md += ["### Plots", "", *(f"![{p.stem}](plots/{p.name})" for p in images), ""]
    write_text_atomic(out / "tables.md", "\n".join(md))
    write_text_atomic(out / "tables.json", json.dumps(data, indent=2) + "\n")
    return data

"""T3, with / without multi-view geometry: semantic against semantic+geometry (and +object)."""

from __future__ import annotations

from typing import Any

from .layout import Layout, select, slam_rows
from .markdown import LABELS, md_table, pct
from .runs_csv import ATE_KEYS
from .stats import improvement, stat


def table_t3(rows, layout: Layout) -> tuple[dict[str, Any], list[str]]:
    data: list[dict[str, Any]] = []
    lines: list[str] = []
    if not layout.adapted or "semantic" not in layout.variants:
        return {"rows": data}, [
            "### T3: with / without multi-view geometry",
            "",
            "Not computed: needs the semantic variant and the adapted model of tables.n_layers.",
            "",
        ]
    extra = [v for v in ("semantic_geometry", "semantic_geometry_object") if v in layout.variants]
    for adapted in layout.adapted:
        for system in layout.systems:
            has = [v for v in extra if select(rows, kind="slam", system=system, variant=v)]
            if "semantic_geometry" not in has:
                continue
            header = ["sequence", "metric", "semantic", "semantic+geometry", "improvement"]
            header += ["semantic+geometry+object"] if "semantic_geometry_object" in has else []
            body = []
            for sequence in layout.sequences:
                for key in ATE_KEYS:
                    sem = stat(slam_rows(rows, system, sequence, "semantic", adapted), key)
                    geo = stat(slam_rows(rows, system, sequence, "semantic_geometry", adapted), key)
                    gain = improvement(sem, geo, key)
                    cells = [sequence, LABELS[key], sem.text(4), geo.text(4), pct(gain)]
                    entry = {
                        "system": system,
                        "config": adapted,
                        "sequence": sequence,
                        "metric": key,
                        "semantic": sem.as_json(),
                        "semantic_geometry": geo.as_json(),
                        "improvement_pct": gain,
                    }
                    if "semantic_geometry_object" in has:
                        obj = stat(
                            slam_rows(rows, system, sequence, "semantic_geometry_object", adapted),
                            key,
                        )
                        cells.append(obj.text(4))
                        entry["semantic_geometry_object"] = obj.as_json()
                    body.append(cells)
                    data.append(entry)
            lines += [
                f"### T3: without / with multi-view geometry ({layout.name(adapted)}, {system})",
                "",
                "Improvement: positive = better with geometry.",
                "",
                *md_table(header, body),
                "",
                *layout.footnote([adapted]),
            ]
    if not lines:
        lines = [
            "### T3: with / without multi-view geometry",
            "",
            "Not computed: no semantic_geometry runs (variants).",
            "",
        ]
    return {"rows": data}, lines

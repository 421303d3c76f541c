"""T2, with / without adversarial transfer learning (ATL) per sequence, and T2 by method."""

from __future__ import annotations

from typing import Any

from .layout import Layout, seg_rows, slam_rows
from .markdown import LABELS, digits, md_table, pct, points_text
from .runs_csv import ALL_SEQUENCES, ATE_KEYS, RATES
from .stats import improvement, points, stat

T2_SEG = ("mIoU", *(f"person_{r}" for r in RATES))


def table_t2(rows, layout: Layout) -> tuple[dict[str, Any], list[str]]:
    data: dict[str, Any] = {"per_sequence": [], "improvement": []}
    lines: list[str] = []
    if layout.source_only is None or not layout.adapted:
        return data, [
            "### T2: with / without ATL",
            "",
            "Not computed: the grid needs source_only and adaptsegnet with tables.n_layers.",
            "",
        ]
    so = layout.source_only
    summary: dict[tuple[str, str], list[str]] = {}
    for adapted in layout.adapted:
        lines += [
            f"### T2: without ATL ({so}) vs with ATL ({adapted})",
            "",
            "Person-mask metrics count frames (the robust-semantic-mapping paper's "
            "Table III: a frame is a true positive when the predicted person mask has IoU "
            ">= 0.5 with the true one); ATE with the semantic filter. Improvement: "
            "positive = better with ATL.",
            "",
        ]
        for sequence in layout.sequences:
            metrics: list[tuple[str, str, list, list]] = [
                (
                    key,
                    LABELS[key],
                    seg_rows(rows, so, sequence),
                    seg_rows(rows, adapted, sequence),
                )
                for key in T2_SEG
            ]
            for system in layout.systems:
                for key in ATE_KEYS:
                    metrics.append(
                        (
                            key,
                            f"{LABELS[key]} ({system})",
                            slam_rows(rows, system, sequence, "semantic", so),
                            slam_rows(rows, system, sequence, "semantic", adapted),
                        )
                    )
            body = []
            for key, label, without_rows, with_rows in metrics:
                without, with_ = stat(without_rows, key), stat(with_rows, key)
                gain = improvement(without, with_, key)
                data["per_sequence"].append(
                    {
                        "sequence": sequence,
                        "metric": label,
                        "without": without.as_json(),
                        "with": with_.as_json(),
                        "improvement_pct": gain,
                        "without_config": so,
                        "with_config": adapted,
                    }
                )
                body.append([label, without.text(digits(key)), with_.text(digits(key)), pct(gain)])
                summary.setdefault((adapted, label), []).append(pct(gain))
            header = [
                "without ATL" + (" †" if layout.target_labels.get(so) else ""),
                "with ATL" + (" †" if layout.target_labels.get(adapted) else ""),
            ]
            lines += [
                f"#### {sequence}",
                "",
                *md_table(["metric", *header, "improvement"], body),
                "",
                *layout.footnote([so, adapted]),
            ]
    lines += [
        "### T2 summary: improvement with ATL per sequence",
        "",
        "The improvement % of the means (the paper's Table 5 layout).",
        "",
    ]
    body = [
        [f"{label} ({layout.name(adapted)})" if len(layout.adapted) > 1 else label, *cells]
        for (adapted, label), cells in summary.items()
    ]
    for (adapted, label), cells in summary.items():
        data["improvement"].append(
            {
                "with_config": adapted,
                "metric": label,
                "per_sequence": dict(zip(layout.sequences, cells, strict=True)),
            }
        )
    lines += [*md_table(["metric", *layout.sequences], body), ""]
    lines += layout.footnote(layout.adapted) if len(layout.adapted) > 1 else []
    return data, lines


def table_methods(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    """T2 by method: one row per method at the tables' depth, with its difference to
    source-only in points."""
    data: list[dict[str, Any]] = []
    if layout.source_only is None or len(layout.methods) < 2:
        return data, []
    so = layout.source_only
    seg_keys = ("mIoU", "IoU_person")
    reference = {k: stat(seg_rows(rows, so, ALL_SEQUENCES), k) for k in seg_keys}
    lines = [
        "### T2 by method: adapted vs source-only",
        "",
        "One row per method (discriminator depth = tables.n_layers): target mIoU and person "
        "IoU (pooled over the labelled evaluation frames) with their difference to source-only "
        "in points (100 × the difference of the means), ATE RMSE [m] with the semantic filter.",
        "",
    ]
    systems = list(layout.systems)
    header = ["configuration", "target mIoU", "Δ mIoU [points]", "IoU person", "Δ [points]"]
    header += [
        f"ATE {seq}" + (f" ({system})" if len(systems) > 1 else "")
        for system in systems
        for seq in layout.sequences
    ]
    body = []
    for config in layout.methods:
        seg = {k: stat(seg_rows(rows, config, ALL_SEQUENCES), k) for k in seg_keys}
        entry: dict[str, Any] = {"config": config}
        cells = [layout.name(config)]
        for k in seg_keys:
            delta = points(seg[k], reference[k])
            entry[k] = seg[k].as_json()
            entry[f"{k}_vs_source_only_points"] = delta
            cells += [seg[k].text(3), points_text(delta)]
        entry["ate_rmse"] = []
        for system in systems:
            for sequence in layout.sequences:
                s_ = stat(slam_rows(rows, system, sequence, "semantic", config), "ate_rmse")
                entry["ate_rmse"].append({"system": system, "sequence": sequence, **s_.as_json()})
                cells.append(s_.text(4))
        data.append(entry)
        body.append(cells)
    return data, [*lines, *md_table(header, body), "", *layout.footnote(layout.methods)]

"""T1, discriminator depth: segmentation of every configuration and its ATE per sequence."""

from __future__ import annotations

from typing import Any

from uss_slam.core.classes import CLASS_NAMES

from .layout import Layout, seg_rows, select, slam_rows
from .markdown import md_table, points_text
from .runs_csv import ALL_SEQUENCES
from .stats import Stat, points, stat


def table_t1(rows, layout: Layout) -> tuple[dict[str, Any], list[str]]:
    classes = [f"IoU_{c}" for c in CLASS_NAMES]
    seg_keys = ["val_mIoU", "mIoU", *classes]
    data: dict[str, Any] = {"segmentation": [], "ate_rmse": []}
    body = []
    reference = (
        stat(seg_rows(rows, layout.source_only, ALL_SEQUENCES), "mIoU")
        if layout.source_only is not None
        else Stat(())
    )
    for config in layout.configs:
        seg = seg_rows(rows, config, ALL_SEQUENCES)
        val = select(rows, kind="train", config=config)
        stats = {"val_mIoU": stat(val, "val_mIoU"), **{k: stat(seg, k) for k in seg_keys[1:]}}
        delta = points(stats["mIoU"], reference)
        data["segmentation"].append(
            {
                "config": config,
                **{k: s.as_json() for k, s in stats.items()},
                "mIoU_vs_source_only_points": delta,
            }
        )
        body.append(
            [
                layout.name(config),
                stats["val_mIoU"].text(3),
                stats["mIoU"].text(3),
                points_text(delta),
                *(stats[k].text(3) for k in classes),
            ]
        )
    header = [
        "configuration",
        "val mIoU",
        "target mIoU",
        "Δ mIoU [points]",
        *(f"IoU {c}" for c in CLASS_NAMES),
    ]
    lines = [
        "### T1a: segmentation by discriminator depth",
        "",
        "Target mIoU and per-class IoU on the labelled frames of every evaluation sequence "
        "(pooled); val mIoU = the exported checkpoint's target validation mIoU; Δ mIoU = target "
        "mIoU minus source-only's, in points (100 × the difference of the means).",
        "",
        *md_table(header, body),
        "",
        *layout.footnote(layout.configs),
    ]
    for system in layout.systems:
        body = []
        for config in layout.configs:
            cells = []
            for sequence in layout.sequences:
                s = stat(slam_rows(rows, system, sequence, "semantic", config), "ate_rmse")
                data["ate_rmse"].append(
                    {"system": system, "config": config, "sequence": sequence, **s.as_json()}
                )
                cells.append(s.text(4))
            body.append([layout.name(config), *cells])
        lines += [
            f"### T1b: ATE RMSE [m] by discriminator depth ({system}, semantic filter)",
            "",
            *md_table(["configuration", *layout.sequences], body),
            "",
            *layout.footnote(layout.configs),
        ]
    return data, lines

"""The downstream ratio ``(ATE_none − ATE_model) / (ATE_none − ATE_oracle)`` per sequence and
seed, and each model's paired difference to source-only."""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from .layout import Layout, select, slam_rows
from .markdown import md_table
from .stats import MDE_FORMULA, Stat, downstream_ratio, paired_interval, paired_text, stat

RATIO_FILTERS = ("semantic", "semantic_geometry")
"""The filters of the downstream ratio tables (each when its SLAM runs were made)."""


def table_ratio(
    rows, layout: Layout
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[str]]:
    """The downstream ratio of every model filter per seed, the paired differences to
    source-only, and their markdown."""
    data: list[dict[str, Any]] = []
    paired_rows: list[dict[str, Any]] = []
    needed = {"none", "oracle", "semantic"}
    if not needed <= set(layout.variants):
        return (
            data,
            paired_rows,
            [
                "### Downstream ratio",
                "",
                "Not computed: needs the variants none, oracle and semantic.",
                "",
            ],
        )
    lines = [
        "### Downstream ratio (ATE_none − ATE_model) / (ATE_none − ATE_oracle)",
        "",
        "Per sequence and seed, for each model filter (the trained models, T0's AdaBN models "
        "and the target oracle, which used target labels): 1 = as good as ground-truth masks, "
        "0 = no better than no filter; — = a run failed, was not made, or the oracle was no "
        "better than no filter. Median and mean ± s.d. over the seeds. Each model's row "
        "\"− source_only\": its ratio minus source-only's, paired by seed (every seed's "
        "difference, on how many seeds it is positive, and the mean with its 95% Student-t "
        "interval over the seeds: an interval above 0 excludes no gain; MDE: the smallest "
        "difference the seeds can detect, footnote).",
        "",
    ]
    # T0's AdaBN models and the target oracle too: the baseline any method must beat, and how
    # close a model trained on target labels comes to the ground-truth masks
    configs = list(
        dict.fromkeys(
            c
            for c in (
                layout.source_only,
                *layout.adabn,
                *layout.adapted,
                *layout.methods,
                layout.oracle,
            )
            if c
        )
    )
    filters = [f for f in RATIO_FILTERS if f in layout.variants]
    for system, variant in ((s, f) for s in layout.systems for f in filters):
        body = []
        shown: list[str] = []  # the models of this table
        paired_shown = False
        per_sequence: dict[tuple[str, str], list[float]] = {}
        baselines = {
            sequence: (
                mean_ate(slam_rows(rows, system, sequence, "none")),
                mean_ate(slam_rows(rows, system, sequence, "oracle")),
            )
            for sequence in layout.sequences
        }
        for config in configs:
            # an AdaBN model has no training of its own: the seeds of its SLAM runs
            seeds = [r["seed"] for r in select(rows, kind="train", config=config)] or sorted(
                {r["seed"] for r in select(rows, kind="slam", config=config)}
            )
            if not any(slam_rows(rows, system, s, variant, config) for s in layout.sequences):
                continue  # this filter was not run with this model
            shown.append(config)
            name = layout.name(config)
            for seed in seeds:
                cells = [name, str(seed)]
                for sequence in layout.sequences:
                    none_, oracle = baselines[sequence]
                    runs = [
                        r
                        for r in slam_rows(rows, system, sequence, variant, config)
                        if r["seed"] == seed
                    ]
                    value = downstream_ratio(none_, mean_ate(runs), oracle)
                    data.append(
                        {
                            "system": system,
                            "filter": variant,
                            "config": config,
                            "seed": seed,
                            "sequence": sequence,
                            "ratio": value,
                        }
                    )
                    if value is not None:
                        per_sequence.setdefault((config, sequence), []).append(value)
                    cells.append("—" if value is None else f"{value:.3f}")
                body.append(cells)
            values = [per_sequence.get((config, s), []) for s in layout.sequences]
            body.append(
                [name, "median", *(f"{statistics.median(v):.3f}" if v else "—" for v in values)]
            )
            body.append([name, "mean ± s.d.", *(Stat(tuple(v)).text(3) for v in values)])
            so = layout.source_only
            if (
                config != so
                and so is not None
                and any(
                    _ratios(data, system, variant, so, sequence) for sequence in layout.sequences
                )
            ):
                cells = [name, f"− {layout.name(so)}"]
                for sequence in layout.sequences:
                    mine = _ratios(data, system, variant, config, sequence)
                    base = _ratios(data, system, variant, layout.source_only, sequence)
                    diffs = [mine[k] - base[k] for k in sorted(mine) if k in base]
                    paired = paired_interval(diffs)
                    paired_rows.append({"system": system, "filter": variant, "config": config,
                                        "sequence": sequence, **paired})  # fmt: skip
                    cells.append(paired_text(paired, with_mde=True))
                body.append(cells)
                paired_shown = True
        if not body:  # no model was run with this filter (e.g. ORB-SLAM3 + geometry)
            continue
        lines += [
            f"#### {system}, {variant.replace('_', '+')}",
            "",
            *md_table(["configuration", "seed", *layout.sequences], body),
            "",
            *layout.footnote(shown),
            *([MDE_FORMULA + ".", ""] if paired_shown else []),
        ]
    return data, paired_rows, lines


def _ratios(data: list[dict[str, Any]], system: str, variant: str, config: str,
            sequence: str) -> dict[int, float]:  # fmt: skip
    """Seed -> downstream ratio of one model filter on one sequence (from ``table_ratio``'s
    rows so far)."""
    return {
        d["seed"]: d["ratio"]
        for d in data
        if d.get("ratio") is not None
        and (d["system"], d["filter"], d["config"], d["sequence"])
        == (system, variant, config, sequence)
    }


def mean_ate(rows: Sequence[Mapping[str, Any]]) -> float | None:
    """The mean ATE RMSE of the successful runs among ``rows`` (None if none)."""
    return stat(rows, "ate_rmse").mean

"""Time per frame of the SLAM runs of each variant."""

from __future__ import annotations

from typing import Any

from ..grid import VARIANTS
from .layout import Layout, select
from .markdown import md_table
from .stats import Stat, stat


def table_timing(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    """Mean wall ms per frame of the SLAM runs of each variant: segmentation (the segmenter's
    whole cost), its dense CRF, the whole run."""
    data: list[dict[str, Any]] = []
    if not any(r.get("total_ms") is not None for r in select(rows, kind="slam")):
        return data, []  # a runs.csv from before the timing columns
    lines: list[str] = []
    keys = ("segmentation_ms", "crf_ms", "total_ms", "fps")
    for system in layout.systems:
        body = []
        for variant in layout.variants:
            runs = select(rows, kind="slam", system=system, variant=variant)
            stats = {k: stat(runs, k) for k in keys}
            if variant not in VARIANTS or not VARIANTS[variant].crf:
                stats["crf_ms"] = Stat(())  # no CRF in these runs
            data.append(
                {
                    "system": system,
                    "variant": variant,
                    **{k: v.as_json() for k, v in stats.items()},
                }
            )
            label = VARIANTS[variant].label if variant in VARIANTS else variant
            body.append([label, *(stats[k].text(1) for k in keys)])
        lines += [
            f"### Time per frame ({system})",
            "",
            "Mean wall milliseconds per frame over every run of the variant (all models and "
            "sequences; the SLAM runs' timing_ms). Segmentation includes the dense CRF; it runs "
            "in the prefetch threads, in parallel with tracking, so it can exceed the total.",
            "",
            *md_table(["variant", "segmentation [ms]", "CRF [ms]", "total [ms]", "frames/s"], body),
            "",
        ]
    return data, lines

"""Dense CRF off / on: segmentation metrics and ATE of each model with CRF runs."""

from __future__ import annotations

from typing import Any

from uss_slam.slam_eval.variants import crf_pairs

from ..grid import VARIANTS
from .layout import Layout, seg_rows, slam_rows
from .markdown import md_table
from .runs_csv import ALL_SEQUENCES
from .stats import stat

CRF_PAIRS = crf_pairs(VARIANTS)
"""(filter variant, the same with the dense CRF), from ``configs/variants.yaml``."""


def table_crf(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    """Dense CRF off / on: segmentation metrics and ATE of each model with CRF runs."""
    data: list[dict[str, Any]] = []
    pairs = [(off, on) for off, on in CRF_PAIRS if on in layout.variants]
    if not layout.crf_configs:
        return data, []
    seg_keys = ("mIoU", "IoU_person", "person_FNR", "person_FPR")
    lines: list[str] = []
    for system in layout.systems:
        header = ["configuration", "filter", "CRF", "target mIoU", "IoU person", "person FNR"]
        header += ["person FPR", *(f"ATE {s}" for s in layout.sequences)]
        body = []
        for config in layout.crf_configs:
            for off, on in pairs or [("semantic", "semantic_crf")]:
                for crf, variant in ((False, off), (True, on)):
                    seg = {
                        k: stat(seg_rows(rows, config, ALL_SEQUENCES, crf=crf), k) for k in seg_keys
                    }
                    ate = {
                        seq: stat(slam_rows(rows, system, seq, variant, config), "ate_rmse")
                        for seq in layout.sequences
                    }
                    data.append(
                        {
                            "system": system,
                            "config": config,
                            "filter": off,
                            "crf": crf,
                            **{k: v.as_json() for k, v in seg.items()},
                            "ate_rmse": {seq: v.as_json() for seq, v in ate.items()},
                        }
                    )
                    body.append(
                        [
                            layout.name(config),
                            VARIANTS[off].label,
                            "on" if crf else "off",
                            *(seg[k].text(3) for k in seg_keys),
                            *(ate[seq].text(4) for seq in layout.sequences),
                        ]
                    )
        lines += [
            f"### Dense CRF off / on ({system})",
            "",
            "The same exported model without and with the dense-CRF refinement of its output "
            "(uss-slam segmenter.crf=true): segmentation metrics pooled over the labelled "
            "evaluation frames, ATE RMSE [m] per sequence; its time is in the timing table.",
            "",
            *md_table(header, body),
            "",
            *layout.footnote(layout.crf_configs),
        ]
    return data, lines

"""``eval.md``: the model and data, the per-class IoU table and the dynamic-mask table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.seg_metrics import RATE_NAMES


def _pct(value: float | None) -> str:
    return "—" if value is None else f"{100 * value:.2f}%"


def markdown(result: dict[str, Any]) -> str:
    """``eval.md``: the model and data, the per-class IoU table and the dynamic-mask table."""
    model, data = result["model"], result["data"]
    where = ", ".join(data.get("roots", [])) or " ".join(data.get("overrides", [])) or "defaults"
    lines = [
        f"# uss-eval: {Path(model['path']).name}",
        "",
        f"Model: `{model['path']}` ({model['kind']}, experiment `{model['experiment']}`). "
        f"Frames: {result['frames']} from {data['source']} ({where}); "
        f"{result['ms_per_frame']:.1f} ms per frame.",
        "",
        "| class | IoU | truth pixels | predicted pixels |",
        "|---|---|---|---|",
    ]
    matrix = np.asarray(result["confusion_matrix"])
    for k, name in enumerate(result["classes"]):
        iou = result["IoU"][name]
        lines.append(
            f"| {name} | {'—' if iou is None else f'{iou:.4f}'} | {int(matrix[k].sum())} | "
            f"{int(matrix[:, k].sum())} |"
        )
    miou = result["mIoU"]
    lines += ["", f"**mIoU {'—' if miou is None else f'{miou:.4f}'}** (mean over the classes "
              "present in truth or prediction).", ""]  # fmt: skip
    mask = result["mask"]
    if mask is not None:
        frames, pooled, mean = mask["frames"], mask["pixels_pooled"], mask["pixels_mean"]
        counts = frames["counts"]
        lines += [
            f"Dynamic mask ({', '.join(result['dynamic_classes'])}) against the truth's: "
            f"frames as the paper's Table III (TP {counts['TP']}, FP {counts['FP']}, TN "
            f"{counts['TN']}, FN {counts['FN']}; correctly segmented = mask IoU >= "
            f"{frames['iou_threshold']:g}), pixels pooled over all frames, and the mean of "
            "per-frame pixel rates.",
            "",
            "| metric | frames | pixels (pooled) | pixels (mean over frames) |",
            "|---|---|---|---|",
        ]
        for name in RATE_NAMES:
            lines.append(
                f"| {name} | {_pct(frames[name])} | {_pct(pooled[name])} | {_pct(mean[name])} |"
            )
        lines.append("")
    if result["overlays"]:
        lines += ["Overlays (truth | prediction): "
                  + ", ".join(f"[{Path(p).name}]({p})" for p in result["overlays"]), ""]  # fmt: skip
    return "\n".join(lines)

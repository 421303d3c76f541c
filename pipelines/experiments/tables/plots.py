"""The tables' plots: T1's mIoU and per-class IoU, the ATE per sequence (matplotlib)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from uss_slam.core.classes import CLASS_NAMES

from ..grid import VARIANTS
from .baselines import BASELINES
from .layout import Layout, seg_rows, slam_rows
from .runs_csv import ALL_SEQUENCES
from .stats import Stat, stat


def bars(
    ax: Any, groups: Sequence[str], series: Sequence[tuple[str, Sequence[Stat]]], scale: float = 1.0
) -> None:
    """Grouped bars of the means with s.d. error bars; failed / empty cells show no bar."""
    import numpy as np

    width = 0.8 / max(len(series), 1)
    x = np.arange(len(groups))
    for k, (label, stats) in enumerate(series):
        means = [scale * s.mean if s.mean is not None else np.nan for s in stats]
        errs = [scale * s.sd if s.sd is not None else 0.0 for s in stats]
        ax.bar(
            x + (k - (len(series) - 1) / 2) * width, means, width, yerr=errs, capsize=3, label=label
        )
    ax.set_xticks(x, groups, rotation=15, fontsize=8)


def write_plots(out: Path, rows: Sequence[Mapping[str, Any]], layout: Layout) -> list[Path]:
    """``t1_miou.png``, ``t1_iou_per_class.png`` and ``ate_per_sequence.png`` in ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []

    def save(fig: Any, name: str) -> None:
        path = out / name
        tmp = out / f".{name}.tmp.png"
        fig.tight_layout()
        fig.savefig(tmp, dpi=110)
        plt.close(fig)
        tmp.replace(path)
        written.append(path)

    configs = list(layout.configs)
    fig, ax = plt.subplots(figsize=(max(5.0, 1.1 * len(configs)), 3.4))
    bars(
        ax,
        configs,
        [("target mIoU", [stat(seg_rows(rows, c, ALL_SEQUENCES), "mIoU") for c in configs])],
    )
    ax.set_ylabel("mIoU")
    ax.set_title("T1: target mIoU by configuration (mean ± s.d. over seeds)")
    save(fig, "t1_miou.png")

    fig, ax = plt.subplots(figsize=(max(6.0, 1.4 * len(CLASS_NAMES) + 2) + 2.0, 3.6))
    bars(
        ax,
        list(CLASS_NAMES),
        [
            (c, [stat(seg_rows(rows, c, ALL_SEQUENCES), f"IoU_{name}") for name in CLASS_NAMES])
            for c in configs
        ],
    )
    ax.set_ylabel("IoU")
    ax.set_title("Per-class IoU on the evaluation sequences (mean ± s.d. over seeds)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    save(fig, "t1_iou_per_class.png")

    series_spec: list[tuple[str, str, str | None]] = [
        (VARIANTS[v].label, v, None) for v in BASELINES if v in layout.variants
    ]
    for config in (layout.source_only, *layout.adapted):
        if config is None:
            continue
        for v in VARIANTS:
            if VARIANTS[v].segmenter == "model" and v in layout.variants:
                series_spec.append((f"{config} {VARIANTS[v].label}", v, config))
    systems = list(layout.systems) or ["harness"]
    fig, axes = plt.subplots(
        len(systems),
        1,
        figsize=(max(7.0, 2.2 * len(layout.sequences)) + 3.0, 3.6 * len(systems)),
        squeeze=False,
    )
    for ax, system in zip(axes[:, 0], systems, strict=True):
        bars(
            ax,
            list(layout.sequences),
            [
                (
                    label,
                    [stat(slam_rows(rows, system, s, v, c), "ate_rmse") for s in layout.sequences],
                )
                for label, v, c in series_spec
            ],
            scale=100.0,
        )
        ax.set_ylabel("ATE RMSE [cm]")
        ax.set_title(f"ATE per sequence ({system}; mean ± s.d. over seeds)")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    save(fig, "ate_per_sequence.png")
    return written

"""The demo's table and plots: one row per SLAM variant (ATE, tracking, speed, segmenter mIoU),
``ate_rmse.png`` (ATE RMSE per variant) and ``trajectories.png`` (every aligned estimate against
the ground truth, drawn by :mod:`uss_slam.slam_eval.scoring.plots`)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import atomic_path

if TYPE_CHECKING:
    from .runs import Variant

TABLE_HEADER = (
    "| variant | filters | ATE RMSE [m] | Mean [m] | Median [m] | S.D. [m] | tracked | "
    "frames/s | seg. [ms/frame] | mIoU | person IoU |"
)
ROW_COLORS = ("0.5", "tab:green", "tab:orange", "tab:blue", "tab:purple")
"""Colour of each variant (in order) in both plots."""
DPI = 110


def fmt(value: Any, digits: int = 4) -> str:
    """``value`` with ``digits`` decimals, an em dash for None."""
    if value is None:
        return "—"
    return f"{value:.{digits}f}"


def summary_rows(
    slam_dir: Path, variants: Sequence[Variant], miou: Mapping[str, Any]
) -> list[dict[str, Any]]:
    """One row per variant: the numbers of the table (from each run's ``metrics.json`` and the
    ``miou`` stage's scores; the oracle's labels score 1 by definition)."""
    rows = []
    for v in variants:
        m = json.loads((slam_dir / v.name / "metrics.json").read_text())
        ate = m["ate"] or {}
        if v.segmenter == "labels":
            seg_iou: Mapping[str, Any] = {"mIoU": 1.0, "IoU": dict.fromkeys(CLASS_NAMES, 1.0)}
        else:
            seg_iou = miou.get(v.model or "", {"mIoU": None, "IoU": {}})
        rows.append(
            {
                "variant": v.name,
                "label": v.label,
                "segmenter": m["segmenter"],
                "filters": list(v.filters),
                "ate_rmse": ate.get("rmse"),
                "ate_mean": ate.get("mean"),
                "ate_median": ate.get("median"),
                "ate_std": ate.get("std"),
                "tracked_fraction": m["tracked_fraction"],
                "fps": m["fps"],
                "segmentation_ms": m["segmentation"]["wall_ms"],
                "mIoU": seg_iou["mIoU"],
                "person_IoU": seg_iou["IoU"].get("person"),
            }
        )
    return rows


def markdown_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """The printed table (Markdown), one line per row."""
    lines = [TABLE_HEADER, "|" + "---|" * TABLE_HEADER.count(" | ") + "---|"]
    for r in rows:
        lines.append(
            f"| {r['label']} | {'+'.join(r['filters']) or '—'} | {fmt(r['ate_rmse'])} | "
            f"{fmt(r['ate_mean'])} | {fmt(r['ate_median'])} | {fmt(r['ate_std'])} | "
            f"{100 * r['tracked_fraction']:.0f}% | {r['fps']:.1f} | "
            f"{fmt(r['segmentation_ms'], 1)} | {fmt(r['mIoU'], 3)} | "
            f"{fmt(r['person_IoU'], 3)} |"
        )
    return "\n".join(lines)


def plot_ate_bars(path: Path, rows: Sequence[Mapping[str, Any]], title: str) -> Path:
    """Bar chart of ATE RMSE (cm) per row, each bar labelled with its value ("n/a" if none)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 3.4))
    ax = fig.add_subplot()
    values = [r["ate_rmse"] if r["ate_rmse"] is not None else 0.0 for r in rows]
    bars = ax.bar(range(len(rows)), [100 * v for v in values], color=ROW_COLORS[: len(rows)])
    for bar, r in zip(bars, rows, strict=True):
        text = "n/a" if r["ate_rmse"] is None else f"{100 * r['ate_rmse']:.2f}"
        ax.text(bar.get_x() + bar.get_width() / 2, bar.get_height(), text, ha="center",
                va="bottom", fontsize=8)  # fmt: skip
    ax.set_xticks(range(len(rows)), [r["label"] for r in rows], rotation=15, fontsize=8)
    ax.set_ylabel("ATE RMSE [cm]")
    ax.set_title(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return path


def plot_aligned_trajectories(
    path: Path, groundtruth: Path, slam_dir: Path, rows: Sequence[Mapping[str, Any]], title: str
) -> Path:
    """Top view of every row's trajectory (``slam_dir/<variant>/trajectory.txt``) aligned to
    ``groundtruth`` (SE(3)); a run that cannot be aligned is left out."""
    from uss_slam.core.tum_io import read_trajectory
    from uss_slam.slam_eval.scoring import metrics, plots

    gt = read_trajectory(groundtruth)
    reference = None
    estimates: list[tuple[str, Any]] = []
    colors: list[str] = []
    for r, color in zip(rows, ROW_COLORS, strict=False):
        est = read_trajectory(slam_dir / r["variant"] / "trajectory.txt")
        try:
            result = metrics.ate(gt, est)
        except UssSlamError:
            continue
        if reference is None:
            reference = result.gt_positions
        estimates.append((r["label"], result.est_positions))
        colors.append(color)
    if reference is None:
        reference = gt.positions
    return plots.plot_trajectories(path, reference, estimates, title, colors=colors)

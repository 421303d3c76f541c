"""The demo's table and plots: one row per SLAM variant (median ATE over the repeats with their
range, tracking, speed, segmenter mIoU), what the numbers say (:func:`findings`),
``ate_rmse.png`` (ATE RMSE per variant) and ``trajectories.png`` (every aligned estimate against
the ground truth, drawn by :mod:`uss_slam.slam_eval.scoring.plots`)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import atomic_path, write_text_atomic

if TYPE_CHECKING:
    from .runs import Variant

TABLE_HEADER = (
    "| variant | filters | ATE RMSE [m], median | min–max [m] | tracked | frames/s | "
    "seg. [ms/frame] | mIoU | person IoU |"
)
ROW_COLORS = ("0.5", "tab:green", "tab:orange", "tab:red", "tab:blue", "tab:purple")
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
        m = json.loads((slam_dir / v.name / "metrics.json").read_text(encoding="utf-8"))
        ate = m["ate"] or {}
        spread = m.get("ate_rmse_repeats") or {"min": ate.get("rmse"), "max": ate.get("rmse")}
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
                "ate_rmse": ate.get("rmse"),  # the median repeat's
                "ate_min": spread["min"],
                "ate_max": spread["max"],
                "repeats": len(m.get("repeats") or [None]),
                "tracked_fraction": m["tracked_fraction"],
                "fps": m["fps"],
                "segmentation_ms": m["segmentation"]["wall_ms"],
                "mIoU": seg_iou["mIoU"],
                "person_IoU": seg_iou["IoU"].get("person"),
                "keypoints": {k: m["keypoints"][k] for k in ("extracted", "kept", "dropped")},
            }
        )
    return rows


def markdown_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """The printed table (Markdown), one line per row."""
    lines = [TABLE_HEADER, "|" + "---|" * TABLE_HEADER.count(" | ") + "---|"]
    for r in rows:
        lines.append(
            f"| {r['label']} | {'+'.join(r['filters']) or '—'} | {fmt(r['ate_rmse'])} | "
            f"{fmt(r['ate_min'])}–{fmt(r['ate_max'])} | "
            f"{100 * r['tracked_fraction']:.0f}% | {r['fps']:.1f} | "
            f"{fmt(r['segmentation_ms'], 1)} | {fmt(r['mIoU'], 3)} | "
            f"{fmt(r['person_IoU'], 3)} |"
        )
    return "\n".join(lines)


def _change(value: float | None, reference: float | None) -> str:
    """``value`` against ``reference`` in percent (signed), "n/a" without both."""
    if value is None or not reference:
        return "n/a"
    return f"{100 * (value - reference) / reference:+.0f}%"


def findings(
    rows: Sequence[Mapping[str, Any]], adapted_training: Mapping[str, Any] | None = None
) -> list[str]:
    """What the table's numbers say, computed from them (no claim beyond its one sequence and
    training seed): each mask row's median ATE against no filter, adapted against source-only
    (and whether their repeats' ranges overlap), and whether geometry helps the adapted masks,
    with the keypoints it dropped when it does not. Rows are those of :func:`summary_rows`
    (``none``, ``source_only``, ``adapted`` and ``adapted_geometry`` needed);
    ``adapted_training``: the adapted training's final metrics, for
    :func:`discriminator_line`."""
    by = {r["variant"]: r for r in rows}
    base, src, ada, geo = (by[n] for n in ("none", "source_only", "adapted", "adapted_geometry"))
    ref = base["ate_rmse"]
    masks = [r for r in rows if r["filters"] == ["semantic"]]
    helping = [r["label"] for r in masks if _lower(r["ate_rmse"], ref)]
    others = [r["label"] for r in masks if r["label"] not in helping]
    first = (
        f"On this sequence (one training seed, median of {base['repeats']} SLAM runs per row), "
        f"against no filter ({fmt(ref)} m): "
        + ", ".join(f"{r['label']} {_ate(r['ate_rmse'], ref)}" for r in masks)
        + "; masks that lower the median ATE: "
        + (_join(helping) if helping else "none")
        + (f"; that do not: {_join(others)}." if others else ".")
    )
    if src["ate_rmse"] is None or ada["ate_rmse"] is None:
        second = "Adapted and source-only cannot be compared: a run has no ATE."
    else:
        diff = ada["ate_rmse"] - src["ate_rmse"]
        verdict = (
            f"Adapted equals source-only ({fmt(ada['ate_rmse'])} m)"
            if round(diff, 4) == 0
            else f"Adapted is {'below' if diff < 0 else 'above'} source-only by "
            f"{abs(diff):.4f} m ({_change(ada['ate_rmse'], src['ate_rmse'])})"
        )
        second = (
            verdict
            + (
                "; their repeats' ranges overlap, so these runs do not separate them"
                if _overlap(src, ada)
                else "; their repeats' ranges do not overlap"
            )
            + _same_masks(src, ada)
            + "."
        )
    lines = [first, second, geometry_line(geo, ada, by.get("labels"))]
    d_line = discriminator_line(adapted_training)
    return lines if d_line is None else [*lines[:2], d_line, lines[2]]


def discriminator_line(metrics: Mapping[str, Any] | None) -> str | None:
    """One line on the adapted training's discriminators from its final metrics (the
    ``train/d_acc_*`` figures :class:`~uss_slam.train.methods.adversarial.DiscriminatorWatch`
    adds): whether they ever told the domains apart. None when the training logged none (a
    method without discriminators, or a run from before they were recorded)."""
    if not metrics or "train/d_at_chance" not in metrics:
        return None
    peaks = (
        f"largest 25-iteration mean of the domain accuracy: main {metrics['train/d_acc_main_peak']:.2f}, "
        f"aux {metrics['train/d_acc_aux_peak']:.2f}; 0.5 is chance"
    )
    if metrics["train/d_at_chance"]:
        return (
            f"The adapted training's discriminators stayed at chance ({peaks}): the adversarial "
            "term did not act, so the adapted row is source-only in another BatchNorm mode, not "
            "adaptation."
        )
    return f"The adapted training's discriminators told the domains apart ({peaks})."


def _same_masks(src: Mapping[str, Any], ada: Mapping[str, Any]) -> str:
    """When the two segmenters' person IoU agree to 3 decimals: their masks are the same, so
    any ATE difference between the rows is SLAM noise (else nothing)."""
    a, s = ada.get("person_IoU"), src.get("person_IoU")
    if a is None or s is None or round(a, 3) != round(s, 3):
        return ""
    return (
        f"; the adapted masks score as source-only's (person IoU {a:.3f} and {s:.3f}), so the "
        "ATE difference is SLAM noise, not adaptation"
    )


def _ate(value: float | None, reference: float | None) -> str:
    """A row's median ATE with its change against ``reference``; "no ATE" for a lost run."""
    return "no ATE" if value is None else f"{fmt(value)} m ({_change(value, reference)})"


def _lower(value: float | None, reference: float | None) -> bool:
    return value is not None and reference is not None and value < reference


def _join(names: Sequence[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _overlap(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Whether two rows' ATE ranges over their repeats overlap (a missing bound: yes)."""
    bounds = (a["ate_min"], a["ate_max"], b["ate_min"], b["ate_max"])
    if any(v is None for v in bounds):
        return True
    return a["ate_min"] <= b["ate_max"] and b["ate_min"] <= a["ate_max"]


def geometry_line(
    geo: Mapping[str, Any], masks: Mapping[str, Any], labels: Mapping[str, Any] | None
) -> str:
    """One line: does the geometry check help the masks (``geo`` row against ``masks``)? When
    it does not, what it dropped: its share of the keypoints the masks kept and, when it dropped
    more than the ground-truth masks (``labels`` row) drop on walkers in the whole sequence, the
    least number of them that were on static structure."""
    a, g = masks["ate_rmse"], geo["ate_rmse"]
    kp = geo["keypoints"]
    dropped = int(kp["dropped"].get("geometry", 0))
    kept_by_masks = int(kp["extracted"]) - int(kp["dropped"].get("semantic", 0))
    share = 100 * dropped / max(kept_by_masks, 1)
    what = f"it dropped {dropped} keypoints, {share:.1f}% of those the masks kept"
    if _lower(g, a) and _overlap(geo, masks):  # the rule of the adapted line: ranges decide
        return (
            f"Geometry lowers the median ATE: {fmt(g)} m against {fmt(a)} m with the masks alone "
            f"({_change(g, a)}); their repeats' ranges overlap, so these runs do not separate "
            f"them; {what}."
        )
    if _lower(g, a):
        return (
            f"Geometry helps: {fmt(g)} m against {fmt(a)} m with the masks alone "
            f"({_change(g, a)}); their repeats' ranges do not overlap; {what}."
        )
    line = (
        f"Geometry does not help here: {fmt(g)} m against {fmt(a)} m with the masks alone "
        f"({_change(g, a)}); {what}"
    )
    walkers = None if labels is None else labels["keypoints"]["dropped"].get("semantic")
    if walkers is not None and dropped > int(walkers):
        line += (
            f", more than the {int(walkers)} the ground-truth masks drop on walkers in the whole "
            f"sequence: at least {dropped - int(walkers)} were on static structure"
        )
    return line + "."


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


CAVEAT = (
    "Data: the tum_like shift (docs/synthetic.md, Domain shifts). One training seed and one "
    "sequence: a single SLAM run's ATE moves 10-50% for a 1% change of the feature budget, and "
    "the repeats' range shows only that part of the noise, not the training's; uss-experiments "
    "gives seeds, sequences and intervals."
)
"""What the demo's table can and cannot show, printed under it and written in report.md."""


def training_metrics(run_dir: Path | None) -> dict[str, Any] | None:
    """A training's final metrics (its ``metrics.json``; None when absent or unreadable)."""
    if run_dir is None:
        return None
    try:
        return dict(json.loads((run_dir / "metrics.json").read_text(encoding="utf-8")))
    except (OSError, ValueError):
        return None


def final_val_miou(run_dir: Path) -> float | None:
    """``val/mIoU`` at the end of a training (its ``metrics.json``; None when absent)."""
    value = (training_metrics(run_dir) or {}).get("val/mIoU")
    return None if value is None else float(value)


def write_report(
    path: Path,
    *,
    title: str,
    slam_seed: int,
    slam_repeats: int,
    miou_stride: int,
    table: str,
    findings: Sequence[str],
    val: Mapping[str, float | None],
    variants: Sequence[Any],
    times: Mapping[str, float],
) -> None:
    """``report.md``: the table, its findings, what the demo did, each run's plots, the time per
    stage (``variants``: the demo's SLAM variants, each with ``name`` and ``label``)."""
    lines = [
        f"# uss-slam demo: {title}",
        "",
        "Synthetic data (`data/`), two trainings of the same segmenter from the pretrained init "
        "that ships with the package, with the same budget — source-only continued and "
        "AdaptSegNet — (`train/`), their ONNX exports and source-only's with target BatchNorm "
        "statistics (AdaBN) (`exports/`), and the SLAM harness on the target-style walking "
        f"sequence (SLAM seed {slam_seed}, rendered for this demo only) with six "
        f"dynamic-point treatments, {slam_repeats} runs each (`slam/<variant>/`, each with "
        "its own report).",
        "",
        table,
        "",
        *(line for finding in findings for line in (finding, "")),
        f"ATE after SE(3) alignment: the median run's RMSE and the range over the "
        f"{slam_repeats} runs (seeded feature-budget and RANSAC perturbations); tracked, "
        f"frames/s and segmentation wall time per segmented frame (in the prefetch threads) of "
        f"the median run; mIoU / person IoU of each segmenter on every {miou_stride}th "
        "frame of the SLAM sequence's labels (ground-truth masks = 1 by definition).",
        "",
        "Exported: each run's last checkpoint (chosen without target labels). Target "
        "validation mIoU at the end of training, for information: "
        + ", ".join(f"{n} {fmt(v, 3)}" for n, v in val.items())
        + ".",
        "",
        CAVEAT,
        "",
        "Baseline-vs-each improvements: [slam/comparison.md](slam/comparison.md).",
        "",
        "![ATE RMSE per variant](ate_rmse.png)",
        "",
        "![aligned trajectories](trajectories.png)",
        "",
        "## Each run",
        "",
    ]
    for v in variants:
        lines += [
            f"### {v.label}",
            "",
            f"[report](slam/{v.name}/report.md)",
            "",
            f"![trajectory](slam/{v.name}/trajectory.png) ![ATE](slam/{v.name}/ate.png)",
            "",
        ]
    lines += [
        "## Time per stage",
        "",
        "| stage | seconds |",
        "|---|---|",
        *(f"| {name} | {seconds:.1f} |" for name, seconds in times.items()),
        "",
    ]
    write_text_atomic(path, "\n".join(lines))

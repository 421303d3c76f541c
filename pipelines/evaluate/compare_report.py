"""The report of ``uss-eval compare``: the printed table, ``report.md`` with its images
(``validators.png``, ``contact_sheet.png``), ``compare.json``, and the verdict.

Verdict rules (one everywhere):

- with labelled frames, a model is named better than another only when the 95% bootstrap
  interval of their paired person-IoU difference (frames clustered by sequence) excludes 0;
  otherwise the report says how many labelled frames a difference of the observed size would
  need (:func:`~uss_slam.core.verdict.frames_needed`);
- without labels, two models' masks are "not separated" when they differ by more than 5% of the
  image on no more than 5% of the frames: nothing a label could tell apart in the masks a SLAM
  filter uses;
- the last line is one sentence the user can act on.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES, colorize
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import StagedFiles
from uss_slam.core.verdict import (
    ScoreIntervals,
    bootstrap_scores,
    frames_needed,
    interval_halfwidth_at,
)

from .compare import MIN_LABELS, CompareResult

HIGHER = {"entropy": True, "im": True, "snd": True, "probe": False, "dynamic_share": None}
NOT_SEPARATED_SHARE = 0.05
"""Masks whose frames differ by > 5% of the image on at most this share of frames: not separated."""
PERSON = CLASS_NAMES.index("person")
CALIBRATION = (
    "On the synthetic benchmark (docs/results/validators.md) choosing checkpoints by entropy, "
    "im or snd did not beat keeping the last one; read them as descriptions, not verdicts."
)
"""What the calibration says, printed under every validator table."""


def fmt(value: float, digits: int = 3) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def intervals(result: CompareResult, draws: int = 2000, seed: int = 0) -> ScoreIntervals | None:
    if result.matrices is None:
        return None
    return bootstrap_scores(result.matrices, result.clusters, PERSON, draws=draws, seed=seed)


def pair_rows(result: CompareResult) -> list[dict[str, Any]]:
    names = [m.name for m in result.plan.models]
    rows = []
    for (a, b), ag in result.agreement.items():
        rows.append({
            "a": names[a], "b": names[b], "mask_iou": ag.iou,
            "frames_differ": ag.frames_differ, "mean_differ": float(ag.differ.mean()),
            "separated": bool(ag.frames_differ > NOT_SEPARATED_SHARE),
        })  # fmt: skip
    return rows


def verdict(result: CompareResult, stats: ScoreIntervals | None) -> tuple[list[str], str]:
    """Lines of findings and the one last sentence."""
    names = [m.name for m in result.plan.models]
    lines: list[str] = []
    pairs = pair_rows(result)
    for p in pairs:
        if not p["separated"]:
            lines.append(
                f"{p['a']} and {p['b']}: masks not separated (dynamic-mask IoU {p['mask_iou']:.3f}; "
                f"{100 * p['frames_differ']:.0f}% of frames differ by more than 5% of the image)."
            )
    if stats is None:
        apart = [p for p in pairs if p["separated"]]
        if not apart:
            return lines, (
                "The models' masks agree on these frames: adaptation changed little here, so keep "
                "the simpler model, or label 20 frames and rerun with --labels for a verdict."
            )
        worst = max(apart, key=lambda p: p["frames_differ"])
        return lines, (
            f"The models disagree ({worst['a']} vs {worst['b']} on "
            f"{100 * worst['frames_differ']:.0f}% of frames): label 20 frames (contact_sheet.png "
            "shows where) and rerun with --labels to learn which is better."
        )
    n = result.matrices.shape[1]
    best = int(np.nanargmax([i.value for i in stats.iou]))
    wins, needs = [], []
    for (a, b), d in stats.diff_iou.items():
        hi, lo = (b, a) if d.value > 0 else (a, b)
        if d.excludes_zero():
            lo_end, hi_end = sorted((abs(d.low), abs(d.high)))
            digits = 1 if abs(d.value) >= 0.01 else 2  # a tenth of a point shows as 0.0 otherwise
            lines.append(
                f"{names[hi]} beats {names[lo]} on person IoU by {abs(100 * d.value):.{digits}f} "
                f"points [{100 * lo_end:.{digits}f}, {100 * hi_end:.{digits}f}] ({n} labelled frames)."
            )
            if hi == best:
                wins.append(lo)
        else:
            need = frames_needed(d, n)
            more = "no difference at all" if need is None else f"about {need} labelled frames"
            lines.append(
                f"{names[a]} vs {names[b]}: person IoU difference {d.text(signed=True)} points "
                f"includes 0 on {n} labelled frames; a difference of this size would need {more}."
            )
            if best in (a, b) and need is not None:
                needs.append(need)
    others = len(names) - 1
    if len(wins) == others:
        return lines, (
            f"Use {names[best]}: its person IoU is higher than every other model's with 95% "
            f"confidence on {n} labelled frames."
        )
    if needs:
        return lines, (
            f"No model is better on {n} labelled frames: label about {max(needs)} frames to tell "
            f"{names[best]} apart, or keep the simpler model."
        )
    return lines, (
        f"No model is better on {n} labelled frames: their person IoUs do not differ, so keep "
        "the simpler model."
    )


def small_label_warning(result: CompareResult, stats: ScoreIntervals | None) -> str | None:
    """The warning for fewer than ``MIN_LABELS`` labelled frames, with the interval they give."""
    if stats is None or result.matrices.shape[1] >= MIN_LABELS:
        return None
    n = result.matrices.shape[1]
    se = max((d.se for d in stats.diff_iou.values() if math.isfinite(d.se)), default=float("nan"))
    at = interval_halfwidth_at(se, n, n) if math.isfinite(se) else float("nan")
    return (
        f"--labels: {n} labelled frames (fewer than {MIN_LABELS}): the person-IoU differences "
        f"have 95% intervals of about +/-{100 * at:.1f} points; {MIN_LABELS} frames would give "
        f"about +/-{100 * interval_halfwidth_at(se, n, MIN_LABELS):.1f}"
    )


def table(result: CompareResult, stats: ScoreIntervals | None) -> str:
    names = list(result.scores)
    cols = list(next(iter(result.scores.values())))
    head = ["model", *cols]
    if stats is not None:
        head += ["person IoU [95%]", "mIoU [95%]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for k, name in enumerate(names):
        cells = [name, *(fmt(result.scores[name][c]) for c in cols)]
        if stats is not None:
            cells += [stats.iou[k].text(), stats.miou[k].text()]
        lines.append("| " + " | ".join(cells) + " |")
    direction = ", ".join(
        f"{c} {'higher' if HIGHER.get(c) else 'lower' if HIGHER.get(c) is False else 'descriptive'}"
        for c in cols
    )
    lines.append(f"\nValidators ({direction} is better by their definition). {CALIBRATION}")
    lines += ["", "| pair | dynamic-mask IoU | frames differing > 5% | mean differing share | separated |",
              "|---|---|---|---|---|"]  # fmt: skip
    for p in pair_rows(result):
        lines.append(
            f"| {p['a']} vs {p['b']} | {p['mask_iou']:.3f} | {100 * p['frames_differ']:.0f}% | "
            f"{100 * p['mean_differ']:.2f}% | {'yes' if p['separated'] else 'no'} |"
        )
    return "\n".join(lines)


def validators_png(result: CompareResult) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result.scores)
    cols = list(next(iter(result.scores.values())))
    fig, axes = plt.subplots(1, len(cols), figsize=(2.6 * len(cols), 2.6), squeeze=False)
    for ax, c in zip(axes[0], cols, strict=True):
        values = [result.scores[n][c] for n in names]
        ax.bar(range(len(names)), [v if math.isfinite(v) else 0 for v in values], color="#4c72b0")
        ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_title(c, fontsize=9)
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def contact_sheet(result: CompareResult) -> bytes | None:
    """One row per frame where the models disagree most: the image, then each model's labels
    over it; a caption strip names the frame and the disagreeing share."""
    if not result.contact:
        return None
    rows = []
    for differ, index, thumb, labels in result.contact:
        panels = [thumb]
        for lab in labels:
            mixed = thumb.astype(np.float32)
            shown = lab > 0
            mixed[shown] = 0.5 * mixed[shown] + 0.5 * colorize(lab)[shown]
            panels.append(mixed.astype(np.uint8))
        row = np.concatenate(panels, axis=1)
        caption = np.full((18, row.shape[1], 3), 255, np.uint8)
        frame = result.plan.frames[index]
        text = f"{frame.sequence}/{frame.name}: masks differ on {100 * differ:.1f}% of the image"
        cv2.putText(
            caption, text, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA
        )
        rows.append(np.concatenate([caption, row]))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    ok, png = cv2.imencode(".png", cv2.cvtColor(np.concatenate(rows), cv2.COLOR_RGB2BGR))
    if not ok:
        raise UssSlamError("contact sheet: could not encode the PNG")
    return png.tobytes()


def summary(
    result: CompareResult, stats: ScoreIntervals | None, lines: list[str], last: str
) -> dict:
    names = [m.name for m in result.plan.models]
    out: dict[str, Any] = {
        "models": [
            {"name": m.name, "path": str(m.path), "sha256": m.sha256} for m in result.plan.models
        ],
        "sequences": result.plan.sequences,
        "frames": len(result.plan.frames),
        "dynamic_classes": list(result.plan.dynamic),
        "validators": result.scores,
        "agreement": pair_rows(result),
        "contact_frames": [
            result.plan.frames[i].sequence + "/" + result.plan.frames[i].name
            for _, i, _, _ in result.contact
        ],  # fmt: skip
        "seconds": result.seconds,
        "findings": lines,
        "verdict": last,
    }
    if stats is not None:
        out["labelled_frames"] = int(result.matrices.shape[1])
        out["person_iou"] = {n: vars(i) for n, i in zip(names, stats.iou, strict=True)}
        out["miou"] = {n: vars(i) for n, i in zip(names, stats.miou, strict=True)}
        out["person_iou_difference"] = {
            f"{names[b]} - {names[a]}": vars(d) for (a, b), d in stats.diff_iou.items()
        }
        out["miou_difference"] = {
            f"{names[b]} - {names[a]}": vars(d) for (a, b), d in stats.diff_miou.items()
        }
    return out


def markdown(result: CompareResult, stats: ScoreIntervals | None, lines: list[str], last: str,
             extra: str = "") -> str:  # fmt: skip
    plan = result.plan
    parts = [
        "# Did adaptation help? Model comparison",
        "",
        f"{len(plan.models)} models on {len(plan.frames)} frames of {', '.join(plan.sequences)} "
        f"(dynamic classes: {', '.join(plan.dynamic)}"
        + (f"; {plan.labelled} labelled frames" if stats is not None else "; no labels")
        + ").",
        "",
        table(result, stats),
        "",
        "![validators per model](validators.png)",
        "",
    ]
    if result.contact:
        parts += ["## Where the models disagree most", "",
                  "Each row: the frame, then " + ", ".join(m.name for m in plan.models)
                  + " (class colours over the image).", "", "![contact sheet](contact_sheet.png)", ""]  # fmt: skip
    if extra:
        parts += [extra, ""]
    parts += ["## Verdict", "", *[f"- {line}" for line in lines], "", last, ""]
    return "\n".join(parts)


def write_report(out: Path, result: CompareResult, stats: ScoreIntervals | None, lines: list[str],
                 last: str, extra: str = "", data: dict | None = None) -> list[str]:  # fmt: skip
    """Write every file under a temporary name, then rename all into ``out``; returns the names."""
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, bytes] = {
        "report.md": markdown(result, stats, lines, last, extra).encode(),
        "validators.png": validators_png(result),
    }
    sheet = contact_sheet(result)
    if sheet is not None:
        files["contact_sheet.png"] = sheet
    body = summary(result, stats, lines, last) | (data or {})
    files["compare.json"] = (json.dumps(body, indent=2, default=float) + "\n").encode()
    with StagedFiles() as staged:
        for name, data_bytes in files.items():
            staged.path(out / name).write_bytes(data_bytes)
        stale = [] if sheet is not None else [out / "contact_sheet.png"]
        staged.commit(remove=stale)
    return list(files)

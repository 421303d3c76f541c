"""The outputs of an ORB-SLAM3 run: ``trajectory.txt`` (the median repeat's), ``metrics.json``,
``report.md`` and the plots.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.classes import CLASS_NAMES

from ...filters.dynamic import SemanticFilter
from ...scoring import plots
from ...scoring.report import STAT_KEYS, EvalConfig, Evaluation
from ...segmenters.base import Segmenter
from ...sequence import TumSequence
from .config import OrbSlam3Config
from .masking import MaskPass
from .repeats import RepeatResult, median_index
from .settings import SettingsInfo
from .vocabulary import read_header


def write_outputs(
    out: Path,
    sequence: TumSequence,
    segmenter: Segmenter,
    semantic: SemanticFilter,
    config: OrbSlam3Config,
    evaluation: EvalConfig,
    info: SettingsInfo,
    fps: int,
    vocabulary: Path,
    mask_pass: MaskPass | None,
    results: list[RepeatResult],
    settings: dict[str, Any] | None,
) -> dict[str, Any]:
    median = results[median_index([r.ate_rmse for r in results])]
    chosen = median.evaluation or Evaluation(None, None, None, "not evaluated")
    n = len(sequence)
    (out / "trajectory.txt").write_bytes(median.trajectory_path.read_bytes())
    rmses = [r.ate_rmse for r in results if r.ate_rmse is not None]
    header = read_header(vocabulary)
    data: dict[str, Any] = {
        "system": "orbslam3",
        "sequence": str(sequence.path),
        "camera": sequence.camera_source,
        "segmenter": getattr(segmenter, "name", "none"),
        "blanked": None
        if mask_pass is None
        else {
            "dynamic_classes": _class_names(semantic),
            "dilation": semantic.dilation,
            "grey": config.blank_value,
            "fraction": mask_pass.blanked_fraction,
            "segmentation_ms": mask_pass.segmentation_ms,
        },
        "frames": n,
        "unmatched_rgb_frames": sequence.unmatched_rgb,
        "frames_tracked": median.state_counts.get("OK", 0),
        "tracked_fraction": median.state_counts.get("OK", 0) / max(n, 1),
        "frames_without_pose": n - len(median.trajectory),
        "tracking_states": median.state_counts,
        "ate": chosen.ate.stats.as_dict() if chosen.ate else None,
        "rpe": _rpe(chosen.rpe, evaluation.rpe_delta, evaluation.rpe_unit),
        "rpe_1s": _rpe(chosen.rpe_1s, 1.0, "seconds"),
        "ate_error": chosen.error,
        "evaluation": {"max_diff": evaluation.max_diff, "align": evaluation.align},
        "ate_rmse_repeats": {
            "median": median.ate_rmse,
            "min": min(rmses) if rmses else None,
            "max": max(rmses) if rmses else None,
            "evaluated": len(rmses),
        },
        "median_repeat": median.index,
        "repeats": [
            {
                "index": r.index,
                "trajectory": str(r.trajectory_path.relative_to(out)),
                "ate_rmse": r.ate_rmse,
                "ate_error": r.evaluation.error if r.evaluation else None,
                "poses": len(r.trajectory),
                "tracking_states": r.state_counts,
                "track_s": r.track_s,
                "fps": n / r.track_s if r.track_s > 0 else None,
                "vocabulary_load_s": r.load_s,
            }
            for r in results
        ],
        "fps": float(np.median([n / r.track_s for r in results if r.track_s > 0] or [0.0])),
        "orbslam3": {
            "settings_file": str(info.path),
            "camera_fps": fps,
            "realtime": config.realtime,
            "vocabulary": str(vocabulary),
            "vocabulary_k_L": [header[0], header[1]],
            "pyorbslam3": _package_version("pyorbslam3"),
        },
    }
    if settings is not None:
        data["settings"] = settings
    (out / "metrics.json").write_text(json.dumps(data, indent=2) + "\n")
    figures = _plots(out, results, chosen, sequence)
    (out / "report.md").write_text(_report_md(data, figures))
    return data


def _class_names(semantic: SemanticFilter) -> list[str]:
    return [CLASS_NAMES[int(i)] for i in semantic.ids]


def _package_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def _rpe(result: Any, delta: float, unit: str) -> dict[str, Any] | None:
    if result is None:
        return None
    return {
        "trans": result.trans.as_dict(),
        "rot_deg": result.rot_deg.as_dict(),
        "delta": delta,
        "unit": unit,
    }


def _plots(
    out: Path, results: list[RepeatResult], chosen: Evaluation, sequence: TumSequence
) -> list[str]:
    if chosen.ate is None:
        return []
    a = chosen.ate
    title = sequence.path.name
    plots.plot_trajectories(
        out / "trajectory.png",
        a.gt_positions,
        [("ORB-SLAM3 (median run)", a.est_positions)],
        f"{title}: trajectory ({a.stats.pairs} poses, aligned)",
    )
    plots.plot_error_over_time(
        out / "ate.png", a.stamps, a.errors, f"{title}: absolute trajectory error"
    )
    estimates = [
        (f"repeat {r.index} ({r.ate_rmse:.4f} m)", r.evaluation.ate.est_positions)
        for r in results
        if r.evaluation is not None and r.evaluation.ate is not None
    ]
    plots.plot_trajectories(
        out / "repeats.png", a.gt_positions, estimates, f"{title}: every repeat (aligned)"
    )
    return ["trajectory.png", "ate.png", "repeats.png"]


def _fmt(value: float | None, digits: int = 4) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _report_md(data: dict[str, Any], figures: list[str]) -> str:
    blanked = data["blanked"]
    masking = (
        "none (segmenter=none)"
        if blanked is None
        else f"{', '.join(blanked['dynamic_classes'])} from segmenter {data['segmenter']}, dilated "
        f"{blanked['dilation']} px, blanked to grey {blanked['grey']} and depth 0 "
        f"({100 * blanked['fraction']:.1f}% of the pixels per frame on average; segmentation "
        f"{blanked['segmentation_ms']:.1f} ms per frame)"
    )
    rep = data["ate_rmse_repeats"]
    states = ", ".join(f"{k} {v}" for k, v in data["tracking_states"].items())
    lines = [
        f"# ORB-SLAM3 run: {Path(data['sequence']).name}",
        "",
        f"- sequence: `{data['sequence']}`; camera: {data['camera']}",
        f"- dynamic pixels: {masking}",
        f"- vocabulary: `{data['orbslam3']['vocabulary']}` (k={data['orbslam3']['vocabulary_k_L'][0]}, "
        f"L={data['orbslam3']['vocabulary_k_L'][1]}); settings: `{data['orbslam3']['settings_file']}`",
        f"- repeats: {len(data['repeats'])}; ATE RMSE median {_fmt(rep['median'])} m "
        f"(min {_fmt(rep['min'])}, max {_fmt(rep['max'])}; {rep['evaluated']} evaluated); "
        f"the median run is repeat {data['median_repeat']} (`trajectory.txt`)",
        f"- median run: {data['frames']} frames, {data['frames_tracked']} tracked (state OK, "
        f"{100 * data['tracked_fraction']:.1f}%); states: {states}; "
        f"{data['frames_without_pose']} frames without a pose in the trajectory; "
        f"{data['unmatched_rgb_frames']} colour frames without depth partner skipped",
        "",
        "## Trajectory error (median run)",
        "",
    ]
    if data["ate"] is None:
        lines += [f"Not evaluated: {data['ate_error']}", ""]
    else:
        lines += [
            "| | RMSE | Mean | Median | S.D. | Min | Max | pairs |",
            "|---|---|---|---|---|---|---|---|",
            "| ATE [m] | "
            + " | ".join(_fmt(data["ate"][k]) for k in STAT_KEYS)
            + f" | {data['ate']['pairs']} |",
        ]
        for key in ("rpe", "rpe_1s"):
            rpe = data[key]
            if rpe is None:
                continue
            unit = f"{rpe['delta']:g} {rpe['unit']}"
            for part, label, digits in (("trans", "trans [m]", 4), ("rot_deg", "rot [deg]", 3)):
                lines.append(
                    f"| RPE {label} / {unit} | "
                    + " | ".join(_fmt(rpe[part][k], digits) for k in STAT_KEYS)
                    + f" | {rpe[part]['pairs']} |"
                )
        lines += [
            "",
            f"Alignment: {data['evaluation']['align']}; association max difference "
            f"{data['evaluation']['max_diff']} s.",
            "",
        ]
    lines += [
        "## Repeats",
        "",
        "| repeat | ATE RMSE [m] | poses | frames OK | frames/s | trajectory |",
        "|---|---|---|---|---|---|",
    ]
    for r in data["repeats"]:
        lines.append(
            f"| {r['index']} | {_fmt(r['ate_rmse'])} | {r['poses']} | "
            f"{r['tracking_states'].get('OK', 0)} | {_fmt(r['fps'], 1)} | `{r['trajectory']}` |"
        )
    lines.append("")
    for figure in figures:
        lines += [f"![{figure}]({figure})", ""]
    return "\n".join(lines)

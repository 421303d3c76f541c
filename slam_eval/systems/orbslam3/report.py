"""The outputs of an ORB-SLAM3 run: ``trajectory.txt`` (the median repeat's) and the
``metrics.json`` of its repeats; ``report.md`` and the plots come from the one report writer of
every system (:func:`~..scoring.report.write_report`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...filters.base import DynamicFilter
from ...scoring.evaluation import EvalConfig, Evaluation, scores_dict
from ...scoring.repeats import median_index
from ...scoring.report import fmt, write_report
from ...scoring.run_folder import RunFolder
from ...segmenters.base import Segmenter
from ...sequence import TumSequence
from .config import OrbSlam3Config
from .masking import MaskPass
from .repeats import RepeatResult
from .settings import SettingsInfo
from .vocabulary import read_header


def write_outputs(
    folder: RunFolder,
    out: Path,
    sequence: TumSequence,
    segmenter: Segmenter,
    masks: Sequence[DynamicFilter],
    config: OrbSlam3Config,
    evaluation: EvalConfig,
    info: SettingsInfo,
    fps: int,
    vocabulary: Path,
    mask_pass: MaskPass | None,
    results: list[RepeatResult],
    settings: dict[str, Any] | None,
    thread: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write the outputs of ORB-SLAM3's ``results`` (every repeat) into ``out`` through
    ``folder`` (staged until its commit), each file atomically: ``trajectory.txt`` (the median
    repeat's), ``metrics.json``, ``report.md`` and the plots (``repeats.png`` holds every
    repeat); ``thread``: the figures of ``segment=thread`` (:mod:`.thread`), kept as
    ``semantic_thread``. Returns the metrics dictionary."""
    median = results[median_index([r.ate_rmse for r in results])]
    chosen = median.evaluation or Evaluation(None, None, None, "not evaluated")
    n = len(sequence)
    with folder.writing(out / "trajectory.txt") as tmp:
        tmp.write_bytes(folder.current(median.trajectory_path).read_bytes())
    rmses = [r.ate_rmse for r in results if r.ate_rmse is not None]
    header = read_header(vocabulary)
    data: dict[str, Any] = {
        "system": "orbslam3",
        "sequence": str(sequence.path),
        "camera": sequence.camera_source,
        "segmenter": getattr(segmenter, "name", "none"),
        "blanked": None if mask_pass is None else _blanked(masks, config, mask_pass),
        "frames": n,
        "unmatched_rgb_frames": sequence.unmatched_rgb,
        "frames_tracked": median.state_counts.get("OK", 0),
        "tracked_fraction": median.state_counts.get("OK", 0) / max(n, 1),
        "frames_without_pose": n - len(median.trajectory),
        "tracking_states": median.state_counts,
        **scores_dict(chosen, evaluation),
        "ate_rmse_repeats": {
            "median": median.ate_rmse,
            "min": min(rmses) if rmses else None,
            "max": max(rmses) if rmses else None,
            "evaluated": len(rmses),
        },
        "median_repeat": median.index,
        "repeats": [_repeat(r, out, n) for r in results],
        "fps": float(np.median([n / r.track_s for r in results if r.track_s > 0] or [0.0])),
        "orbslam3": {
            "settings_file": str(info.path),
            "camera_fps": fps,
            "realtime": config.realtime,
            "vocabulary": str(vocabulary),
            "vocabulary_k_L": [header[0], header[1]],
            "pyorbslam3": _package_version("pyorbslam3"),
        },
        **({} if thread is None else {"semantic_thread": thread}),
    }
    if settings is not None:
        data["settings"] = settings
    repeats = [
        (f"repeat {r.index} ({r.ate_rmse:.4f} m)", r.evaluation.ate.est_positions)
        for r in results
        if r.evaluation is not None and r.evaluation.ate is not None
    ]
    write_report(
        folder,
        out,
        data,
        chosen,
        heading=f"ORB-SLAM3 run: {sequence.path.name}",
        summary=_summary_md(data),
        sections=_repeats_md(data),
        error_heading="Trajectory error (median run)",
        estimate="ORB-SLAM3 (median run)",
        repeats=repeats,
    )
    return data


def _blanked(
    masks: Sequence[DynamicFilter], config: OrbSlam3Config, mask_pass: MaskPass
) -> dict[str, Any]:
    """What was blanked in ORB-SLAM3's input: the filters, their settings, the fill, the
    blanked fraction and the segmentation's cost."""
    return {
        "filters": [f.name for f in masks],
        **{k: v for f in masks for k, v in f.input_settings().items()},
        "grey": config.blank_value,
        "fill": config.blank_fill,
        "fill_ms": mask_pass.fill_ms,
        "fraction": mask_pass.blanked_fraction,
        "segmentation_ms": mask_pass.segmentation_ms,
    }


def _repeat(r: RepeatResult, out: Path, n: int) -> dict[str, Any]:
    """One repeat's entry of ``metrics.json`` (``n`` frames in the sequence)."""
    return {
        "index": r.index,
        "trajectory": str(r.trajectory_path.relative_to(out)),
        "ate_rmse": r.ate_rmse,
        "ate_error": r.evaluation.error if r.evaluation else None,
        "poses": len(r.trajectory),
        "tracking_states": r.state_counts,
        "track_s": r.track_s,
        "fps": n / r.track_s if r.track_s > 0 else None,
        "vocabulary_load_s": r.load_s,
        **({"semantic_thread": r.thread} if r.thread else {}),
    }


def _package_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def _fill_text(blanked: dict[str, Any]) -> str:
    if blanked["fill"] == "grey":
        return f"blanked to grey {blanked['grey']}"
    return f"inpainted ({blanked['fill_ms']:.0f} ms per frame)"


def _what_text(blanked: dict[str, Any], segmenter: str) -> str:
    """What was blanked: the classes and their dilation (the semantic filter's settings), else
    the pixels of the filters that found them."""
    if "dynamic_classes" in blanked and "dilation" in blanked:
        return (
            f"{', '.join(blanked['dynamic_classes'])} from segmenter {segmenter}, dilated "
            f"{blanked['dilation']} px"
        )
    return f"the pixels of filters {', '.join(blanked['filters'])} from segmenter {segmenter}"


def _summary_md(data: dict[str, Any]) -> list[str]:
    blanked = data["blanked"]
    masking = (
        "none (segmenter=none)"
        if blanked is None
        else f"{_what_text(blanked, data['segmenter'])}, {_fill_text(blanked)} and depth 0 "
        f"({100 * blanked['fraction']:.1f}% of the pixels per frame on average; segmentation "
        f"{blanked['segmentation_ms']:.1f} ms per frame)"
    )
    rep = data["ate_rmse_repeats"]
    states = ", ".join(f"{k} {v}" for k, v in data["tracking_states"].items())
    orb = data["orbslam3"]
    return [
        f"- sequence: `{data['sequence']}`; camera: {data['camera']}",
        f"- dynamic pixels: {masking}",
        f"- vocabulary: `{orb['vocabulary']}` (k={orb['vocabulary_k_L'][0]}, "
        f"L={orb['vocabulary_k_L'][1]}); settings: `{orb['settings_file']}`",
        f"- repeats: {len(data['repeats'])}; ATE RMSE median {fmt(rep['median'])} m "
        f"(min {fmt(rep['min'])}, max {fmt(rep['max'])}; {rep['evaluated']} evaluated); "
        f"the median run is repeat {data['median_repeat']} (`trajectory.txt`)",
        f"- median run: {data['frames']} frames, {data['frames_tracked']} tracked (state OK, "
        f"{100 * data['tracked_fraction']:.1f}%); states: {states}; "
        f"{data['frames_without_pose']} frames without a pose in the trajectory; "
        f"{data['unmatched_rgb_frames']} colour frames without depth partner skipped",
    ]


def _repeats_md(data: dict[str, Any]) -> list[str]:
    lines = [
        "## Repeats",
        "",
        "| repeat | ATE RMSE [m] | poses | frames OK | frames/s | trajectory |",
        "|---|---|---|---|---|---|",
    ]
    for r in data["repeats"]:
        lines.append(
            f"| {r['index']} | {fmt(r['ate_rmse'])} | {r['poses']} | "
            f"{r['tracking_states'].get('OK', 0)} | {fmt(r['fps'], 1)} | `{r['trajectory']}` |"
        )
    lines.append("")
    return lines

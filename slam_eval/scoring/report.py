"""Run outputs: ``trajectory.txt``, ``metrics.json``, ``report.md``, plots, ``map.ply`` (and
``octomap.ot`` with ``slam.map.octomap=true``); and the
comparison table of several filter sets on one sequence (baseline vs each, improvement %).

``metrics.json`` keys: ``ate`` (``rmse mean median std min max pairs``, metres, SE(3)-aligned by
default) and ``rpe`` (``trans`` metres / ``rot_deg`` degrees, each with the same statistics, over
``rpe_delta`` frames by default 1) — both null when the sequence has no ground truth or too few
tracked poses associate (``ate_error`` says why) — plus ``rpe_1s`` (drift per second), ``frames``,
``frames_tracked``, ``tracked_fraction``, ``keypoints`` (extracted / kept / flagged and dropped
per filter), ``timing_ms`` (mean wall ms per frame of each module and ``total``), ``cpu_ms``
(mean CPU ms per frame of each module), ``fps`` and ``pipeline_to_orb_ratio`` (total wall time /
ORB-extraction wall time of the same run; below 1 is possible, as extraction runs in parallel),
and ``segmentation``: ``schedule`` (``every_frame`` | ``keyframes``), ``thread`` (``prefetch``:
concurrently with ORB extraction; ``main``), ``frames_segmented``, ``wall_ms`` / ``cpu_ms`` per
segmented frame, next to ``orb_wall_ms`` / ``orb_cpu_ms`` per frame for comparison; the back
end: ``local_ba`` (null when off, else ``runs``, mean ``wall_ms`` per run, ``keyframes_culled``,
``observations_erased``, ``mean_free_keyframes``, ``mean_points``), ``loop_closing`` (on/off),
``loop_closures`` (how many) and ``loop_closure_frames`` (per closure: ``frame``, ``stamp``,
``keyframe``, ``loop_frame``, ``loop_keyframe``, ``inliers``, ``correction_m``,
``correction_deg``, ``fused`` points, ``wall_ms``), ``loop_candidates_rejected`` (recognised
places that failed the geometric verification); ``octomap`` (null when off, else ``resolution``,
``occupied_voxels``, ``occupied_per_class`` by class name, ``measured_voxels_carved``,
``tree_nodes``, ``cpu_ms_per_keyframe``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import StrPath, Trajectory, write_trajectory

from ..mapping.semantic_map import write_ply
from ..systems.harness import RunResult
from . import metrics, plots
from .run_folder import RunFolder

STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max")


@dataclass(frozen=True)
class EvalConfig:
    """How trajectories are scored (TUM / evo conventions)."""

    max_diff: float = metrics.DEFAULT_MAX_DIFF
    """Largest rgb stamp <-> ground-truth stamp difference of an associated pair, seconds."""
    align: str = "se3"
    """Umeyama alignment of the estimate: ``se3`` | ``sim3`` | ``none``."""
    rpe_delta: float = 1.0
    """RPE pair distance in ``rpe_unit`` (``metrics.json`` also has ``rpe_1s``, per second)."""
    rpe_unit: str = "frames"
    """``frames`` | ``seconds``."""

    def __post_init__(self) -> None:
        # Messages start with the field name: uss-slam prefixes the config section.
        if not (math.isfinite(self.max_diff) and self.max_diff >= 0):
            raise ValueError(f"max_diff must be a number of seconds >= 0, got {self.max_diff}")
        if self.align not in metrics.ALIGNMENTS:
            raise ValueError(
                f"align must be one of {', '.join(metrics.ALIGNMENTS)}, got {self.align!r}"
            )
        if self.rpe_unit not in metrics.DELTA_UNITS:
            raise ValueError(
                f"rpe_unit must be one of {', '.join(metrics.DELTA_UNITS)}, got {self.rpe_unit!r}"
            )
        if not (math.isfinite(self.rpe_delta) and self.rpe_delta > 0):
            raise ValueError(f"rpe_delta must be > 0, got {self.rpe_delta}")
        if self.rpe_unit == "frames" and not float(self.rpe_delta).is_integer():
            raise ValueError(
                f"rpe_delta must be a whole number of frames with rpe_unit=frames, "
                f"got {self.rpe_delta}"
            )


@dataclass
class Evaluation:
    """ATE / RPE of a run, or why they could not be computed."""

    ate: metrics.AteResult | None
    rpe: metrics.RpeResult | None
    rpe_1s: metrics.RpeResult | None
    error: str | None = None


def evaluate(
    trajectory: Trajectory, groundtruth: Trajectory | None, config: EvalConfig
) -> Evaluation:
    """Score ``trajectory`` against ``groundtruth`` (None -> nothing to score)."""
    if groundtruth is None:
        return Evaluation(None, None, None, "the sequence has no groundtruth.txt")
    if len(trajectory) < metrics.MIN_ASSOCIATED_POSES:
        return Evaluation(
            None, None, None, f"only {len(trajectory)} frames were tracked; ATE needs 3 poses"
        )
    try:
        ate = metrics.ate(groundtruth, trajectory, max_diff=config.max_diff, align=config.align)
        rpe = metrics.rpe(
            groundtruth,
            trajectory,
            delta=config.rpe_delta,
            unit=config.rpe_unit,
            max_diff=config.max_diff,
        )
    except UssSlamError as err:
        return Evaluation(None, None, None, str(err))
    try:
        rpe_1s = metrics.rpe(
            groundtruth, trajectory, delta=1.0, unit="seconds", max_diff=config.max_diff
        )
    except UssSlamError:
        rpe_1s = None  # shorter than a second, or gaps everywhere: reported as null
    return Evaluation(ate, rpe, rpe_1s)


def _rpe_dict(result: metrics.RpeResult | None, delta: float, unit: str) -> dict | None:
    if result is None:
        return None
    return {
        "trans": result.trans.as_dict(),
        "rot_deg": result.rot_deg.as_dict(),
        "delta": delta,
        "unit": unit,
    }


def metrics_dict(result: RunResult, evaluation: Evaluation, config: EvalConfig) -> dict[str, Any]:
    """The content of ``metrics.json``."""
    orb = result.timing_ms.get("orb", 0.0)
    return {
        "sequence": result.sequence,
        "camera": result.camera,
        "segmenter": result.segmenter,
        "filters": result.filters,
        "frames": result.frames,
        "frames_tracked": result.tracked,
        "tracked_fraction": result.tracked_fraction,
        "unmatched_rgb_frames": result.unmatched_rgb,
        "ate": evaluation.ate.stats.as_dict() if evaluation.ate else None,
        "rpe": _rpe_dict(evaluation.rpe, config.rpe_delta, config.rpe_unit),
        "rpe_1s": _rpe_dict(evaluation.rpe_1s, 1.0, "seconds"),
        "ate_error": evaluation.error,
        "evaluation": {"max_diff": config.max_diff, "align": config.align},
        "keyframes": result.keyframes,
        "map_points": result.map_points,
        "culled_map_points": result.culled_points,
        "relocalisations": result.relocalisations,
        "lost_events": result.lost_events,
        "keypoints": result.keypoints,
        "timing_ms": result.timing_ms,
        "cpu_ms": result.cpu_ms,
        "fps": result.fps,
        "wall_time_s": result.wall_time_s,
        "pipeline_to_orb_ratio": result.timing_ms["total"] / orb if orb > 0 else None,
        "segmentation": {
            "schedule": result.segment,
            "thread": result.segmentation_thread,
            "frames_segmented": result.segmented_frames,
            "wall_ms": result.segmentation_ms.get("wall"),
            "cpu_ms": result.segmentation_ms.get("cpu"),
            "orb_wall_ms": orb,
            "orb_cpu_ms": result.cpu_ms.get("orb", 0.0),
        },
        "semantic_map_points": len(result.cloud),
        "octomap": result.octomap.summary() if result.octomap is not None else None,
        "local_ba": result.local_ba,
        "loop_closing": result.loop_closing,
        "loop_closures": len(result.loop_closures),
        "loop_closure_frames": result.loop_closures,
        "loop_candidates_rejected": result.loop_candidates_rejected,
    }


def _fmt(value: float | None, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    return f"{value:.{digits}f}"


def _plots(out: Path, evaluation: Evaluation, title: str) -> list[str]:
    """Top view of aligned trajectory vs ground truth and ATE over time; returns file names."""
    if evaluation.ate is None:
        return []
    a = evaluation.ate
    plots.plot_trajectories(
        out / "trajectory.png",
        a.gt_positions,
        [("estimate", a.est_positions)],
        f"{title}: trajectory ({a.stats.pairs} poses, aligned)",
    )
    plots.plot_error_over_time(
        out / "ate.png", a.stamps, a.errors, f"{title}: absolute trajectory error"
    )
    return ["trajectory.png", "ate.png"]


def write_run(
    out_dir: StrPath,
    result: RunResult,
    evaluation: Evaluation,
    config: EvalConfig,
    settings: dict[str, Any] | None = None,
    folder: RunFolder | None = None,
) -> dict[str, Any]:
    """Write every output of one run into ``out_dir``, each file atomically; returns the metrics
    dictionary. ``folder``: the run folder (inside which ``out_dir`` lies) that records the files
    for its manifest; None writes without one."""
    out = Path(out_dir)
    folder = folder or RunFolder(out)
    out.mkdir(parents=True, exist_ok=True)
    with folder.writing(out / "trajectory.txt") as tmp:
        write_trajectory(
            tmp,
            result.trajectory,
            comment=f"uss-slam estimate, filters={result.filters}, camera-to-world",
        )
    data = metrics_dict(result, evaluation, config)
    if settings is not None:
        data["settings"] = settings
    folder.write_text(
        out / "metrics.json", json.dumps(data, indent=2, default=_json_default) + "\n"
    )
    with folder.writing(out / "map.ply") as tmp:
        write_ply(tmp, result.cloud)
    if result.octomap is not None:
        with folder.writing(out / "octomap.ot") as tmp:
            result.octomap.write(tmp)
    title = Path(result.sequence).name
    names = _plots(out, evaluation, title)
    for name in names:
        folder.record(out / name)
    folder.write_text(out / "report.md", _report_md(result, evaluation, data, names))
    return data


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _report_md(
    result: RunResult, evaluation: Evaluation, data: dict[str, Any], plots: list[str]
) -> str:
    filters = ", ".join(result.filters) or "none (baseline)"
    lines = [
        f"# uss-slam run: {Path(result.sequence).name}",
        "",
        f"- sequence: `{result.sequence}`",
        f"- camera: {result.camera}",
        f"- segmenter: {result.segmenter}; filters: {filters}",
        f"- frames: {result.frames} processed, {result.tracked} tracked "
        f"({100 * result.tracked_fraction:.1f}%), {result.unmatched_rgb} colour frames without "
        "depth partner skipped",
        f"- keyframes: {result.keyframes}; map points: {result.map_points} "
        f"({result.culled_points} culled); relocalisations: {result.relocalisations} "
        f"after {result.lost_events} tracking losses",
        "",
        "## Trajectory error",
        "",
    ]
    if evaluation.ate is None:
        lines += [f"Not evaluated: {evaluation.error}", ""]
    else:
        ate = evaluation.ate.stats
        lines += [
            "| | RMSE | Mean | Median | S.D. | Min | Max | pairs |",
            "|---|---|---|---|---|---|---|---|",
            "| ATE [m] | "
            + " | ".join(_fmt(getattr(ate, k)) for k in STAT_KEYS)
            + f" | {ate.pairs} |",
        ]
        for key, label in (("rpe", "RPE"), ("rpe_1s", "RPE")):
            rpe = data.get(key)
            if rpe is None:
                continue
            unit = f"{rpe['delta']:g} {rpe['unit']}"
            lines.append(
                f"| {label} trans [m] / {unit} | "
                + " | ".join(_fmt(rpe["trans"][k]) for k in STAT_KEYS)
                + f" | {rpe['trans']['pairs']} |"
            )
            lines.append(
                f"| {label} rot [deg] / {unit} | "
                + " | ".join(_fmt(rpe["rot_deg"][k], 3) for k in STAT_KEYS)
                + f" | {rpe['rot_deg']['pairs']} |"
            )
        lines.append("")
        lines.append(
            f"Alignment: {data['evaluation']['align']}; association max difference "
            f"{data['evaluation']['max_diff']} s."
        )
        lines.append("")
    kp = result.keypoints
    lines += [
        "## Keypoints",
        "",
        f"{kp['extracted']} extracted ({kp['per_frame']:.0f} per frame), {kp['kept']} kept.",
        "",
    ]
    if result.filters:
        lines += ["| filter | flagged | dropped (new) | judged |", "|---|---|---|---|"]
        for name in result.filters:
            lines.append(
                f"| {name} | {kp['flagged'][name]} | {kp['dropped'][name]} | "
                f"{kp['checked'][name]} |"
            )
        lines.append("")
    lines += [
        "## Time per frame",
        "",
        "| module | wall [ms] | CPU [ms] |",
        "|---|---|---|",
    ]
    for name, ms in result.timing_ms.items():
        cpu = result.cpu_ms.get(name)
        lines.append(f"| {name} | {ms:.2f} | {'—' if cpu is None else f'{cpu:.2f}'} |")
    ratio = data["pipeline_to_orb_ratio"]
    seg = data["segmentation"]
    where = (
        "in the prefetch threads, concurrently with ORB extraction"
        if seg["thread"] == "prefetch"
        else "in the main thread"
    )
    schedule = "every frame" if seg["schedule"] == "every_frame" else "keyframes only"
    lines += [
        "",
        f"{result.fps:.1f} frames/s end to end; pipeline / ORB extraction time = {_fmt(ratio, 2)}.",
        "",
        f"Segmentation ({result.segmenter}, {schedule}, {where}): {seg['frames_segmented']} of "
        f"{result.frames} frames segmented, {_fmt(seg['wall_ms'], 2)} ms wall / "
        f"{_fmt(seg['cpu_ms'], 2)} ms CPU per segmented frame; ORB extraction "
        f"{seg['orb_wall_ms']:.2f} ms wall / {seg['orb_cpu_ms']:.2f} ms CPU per frame.",
        "",
        f"Semantic map: `map.ply`, {len(result.cloud)} points.",
        "",
    ]
    if data.get("octomap") is not None:
        octo = data["octomap"]
        per_class = ", ".join(f"{k} {v}" for k, v in octo["occupied_per_class"].items())
        lines += [
            f"Semantic OctoMap: `octomap.ot`, {octo['resolution']:g} m voxels, "
            f"{octo['occupied_voxels']} occupied ({per_class}); "
            f"{octo['measured_voxels_carved']} measured voxels carved free by later rays; "
            f"{octo['cpu_ms_per_keyframe']:.1f} ms CPU per keyframe.",
            "",
        ]
    lines += _backend_md(result)
    for plot in plots:
        lines += [f"![{plot}]({plot})", ""]
    return "\n".join(lines)


def _backend_md(result: RunResult) -> list[str]:
    """The back-end section of ``report.md`` (empty when the back end is off)."""
    if result.local_ba is None and not result.loop_closing:
        return []
    lines = ["## Back end", ""]
    ba = result.local_ba
    if ba is None:
        lines.append("Local bundle adjustment: off.")
    else:
        lines.append(
            f"Local bundle adjustment: {ba['runs']} runs, {ba['wall_ms']:.1f} ms each "
            f"({ba['mean_free_keyframes']:.1f} keyframes and {ba['mean_points']:.0f} points "
            f"optimised on average); {ba['observations_erased']} outlier observations erased; "
            f"{ba['keyframes_culled']} redundant keyframes culled."
        )
    lines.append("")
    if not result.loop_closing:
        lines += ["Loop closing: off.", ""]
        return lines
    closures = result.loop_closures
    lines += [
        f"Loop closing: {len(closures)} loop(s) closed; {result.loop_candidates_rejected} "
        "recognised place(s) failed the geometric verification.",
        "",
    ]
    if closures:
        lines += [
            "| frame | loop frame | inliers | correction [m] | correction [deg] | fused | ms |",
            "|---|---|---|---|---|---|---|",
        ]
        for c in closures:
            lines.append(
                f"| {c['frame']} | {c['loop_frame']} | {c['inliers']} | "
                f"{c['correction_m']:.4f} | {c['correction_deg']:.3f} | {c['fused']} | "
                f"{c['wall_ms']:.0f} |"
            )
        lines.append("")
    return lines


# ---------------------------------------------------------------------- comparison


def improvement(baseline: float | None, value: float | None) -> float | None:
    """``(baseline - value) / baseline`` in percent, as the papers' improvement tables."""
    if baseline is None or value is None or baseline == 0:
        return None
    return 100.0 * (baseline - value) / baseline


def write_comparison(
    out_dir: StrPath, runs: dict[str, dict[str, Any]], folder: RunFolder | None = None
) -> str:
    """``comparison.md`` / ``comparison.json`` over runs (name -> metrics dict, baseline first).

    Rows: ATE RMSE / Mean / Median / S.D., RPE translation RMSE, tracked fraction, frames/s;
    columns: each run, and for every run after the first its improvement over the first (%).
    Returns the Markdown table.
    """
    names = list(runs)
    base = names[0]
    rows: list[tuple[str, Any]] = [
        ("ATE RMSE [m]", lambda m: (m["ate"] or {}).get("rmse")),
        ("ATE Mean [m]", lambda m: (m["ate"] or {}).get("mean")),
        ("ATE Median [m]", lambda m: (m["ate"] or {}).get("median")),
        ("ATE S.D. [m]", lambda m: (m["ate"] or {}).get("std")),
        ("RPE trans RMSE [m]", lambda m: ((m["rpe"] or {}).get("trans") or {}).get("rmse")),
        ("RPE rot RMSE [deg]", lambda m: ((m["rpe"] or {}).get("rot_deg") or {}).get("rmse")),
    ]
    header = ["metric", *names] + [f"{n} vs {base}" for n in names[1:]]
    lines = [
        f"# Filter comparison: {Path(runs[base]['sequence']).name}",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    table: dict[str, dict[str, Any]] = {}
    for label, get in rows:
        values = [get(runs[n]) for n in names]
        gains = [improvement(values[0], v) for v in values[1:]]
        table[label] = {
            **dict(zip(names, values, strict=True)),
            **{f"{n} improvement %": g for n, g in zip(names[1:], gains, strict=True)},
        }
        digits = 3 if "deg" in label else 4
        cells = [_fmt(v, digits) for v in values] + [
            "—" if g is None else f"{g:.1f}%" for g in gains
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    for label, key, digits in (
        ("tracked fraction", "tracked_fraction", 3),
        ("frames/s", "fps", 1),
    ):
        values = [runs[n][key] for n in names]
        table[label] = dict(zip(names, values, strict=True))
        cells = [label, *(_fmt(v, digits) for v in values), *([""] * (len(names) - 1))]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(
        "Improvement = (baseline − run) / baseline, as in the papers' tables; "
        "each run's own report is in its sub-folder."
    )
    text = "\n".join(lines) + "\n"
    out = Path(out_dir)
    folder = folder or RunFolder(out)
    folder.write_text(out / "comparison.md", text)
    folder.write_text(
        out / "comparison.json",
        json.dumps({"runs": names, "table": table}, indent=2, default=_json_default) + "\n",
    )
    return text

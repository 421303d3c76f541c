"""The outputs of a SLAM run, one writer for every system: :func:`write_report` writes
``metrics.json``, the plots (``trajectory.png``, ``ate.png``; ``repeats.png`` for repeated runs)
and ``report.md`` (the system's summary, the trajectory-error table, the system's sections).
:func:`write_run` writes a harness run through it (with ``trajectory.txt``, ``map.ply``, and
``octomap.ot`` with ``slam.map.octomap=true``), :mod:`..systems.orbslam3.report` an ORB-SLAM3
run; :func:`write_comparison` writes the comparison table of several filter sets on one sequence
(baseline vs each, improvement %).

The harness's ``metrics.json`` keys: ``ate`` (``rmse mean median std min max pairs``, metres, SE(3)-aligned by
default) and ``rpe`` (``trans`` metres / ``rot_deg`` degrees, each with the same statistics, over
``rpe_delta`` frames by default 1) — both null when the sequence has no ground truth or too few
tracked poses associate (``ate_error`` says why) — plus ``rpe_1s`` (drift per second), ``ate_bands`` (``window_s``, ``rmse``, ``slow``, ``fast``:
the ATE's part that persists over half a second and the per-frame rest), ``frames``,
``frames_tracked``, ``tracked_fraction``, ``keypoints`` (extracted / kept / flagged and dropped
per filter), ``timing_ms`` (mean wall ms per frame of each module and ``total``), ``cpu_ms``
(mean CPU ms per frame of each module), ``fps`` and ``pipeline_to_orb_ratio`` (total wall time /
ORB-extraction wall time of the same run; below 1 is possible, as extraction runs in parallel),
and ``segmentation``: ``schedule`` (``every_frame`` | ``keyframes`` | ``thread``), ``thread``
(``prefetch``: concurrently with ORB extraction; ``main``; ``semantic``), ``frames_segmented``,
``wall_ms`` / ``cpu_ms`` per segmented frame, ``semantic_thread`` (null, or with
``segment=thread`` its ``clock``, ``requested``, ``skipped``, ``delivered``, ``mean_delay_s``,
``mean_segment_s``, ``points_marked``), next to ``orb_wall_ms`` / ``orb_cpu_ms`` per frame for comparison;
``rolling_shutter``: ``readout`` the seconds the tracker corrected for (0 = none),
``readout_from`` and ``frames_corrected``; the back end: ``local_ba`` (null when off, else ``runs``, mean ``wall_ms`` per run, ``keyframes_culled``,
``observations_erased``, ``mean_free_keyframes``, ``mean_points``, ``depth_noise`` the k of
``σ_z = k·z²`` its stereo factors model (0 = ORB-SLAM2's model), ``depth_noise_from``, and
``keyframes_deferred`` / ``keyframes_skipped`` by ``local_ba_params.min_interval_s``),
``loop_closing`` (on/off),
``loop_closures`` (how many) and ``loop_closure_frames`` (per closure: ``frame``, ``stamp``,
``keyframe``, ``loop_frame``, ``loop_keyframe``, ``inliers``, ``correction_m``,
``correction_deg``, ``fused`` points, ``wall_ms``), ``loop_candidates_rejected`` (recognised
places that failed the geometric verification); ``octomap`` (null when off, else ``resolution``,
``occupied_voxels``, ``occupied_per_class`` by class name, ``measured_voxels_carved``,
``tree_nodes``, ``cpu_ms_per_keyframe``). With ``slam.repeats`` > 1 the folder holds the median
run and ``metrics.json`` adds ``ate_rmse_repeats`` and ``rpe_trans_rmse_repeats`` (``median min
max evaluated``), ``median_repeat`` and ``repeats`` (one entry per run; :mod:`.repeats`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.tum_io import StrPath, write_trajectory

from ..products.semantic_map import write_ply
from . import plots
from .evaluation import STAT_KEYS, EvalConfig, Evaluation, scores_dict
from .repeats import repeats_md
from .run_folder import RunFolder
from .run_result import RunResult


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
        **scores_dict(evaluation, config),
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
            "semantic_thread": result.semantic_thread,
            "orb_wall_ms": orb,
            "orb_cpu_ms": result.cpu_ms.get("orb", 0.0),
        },
        "semantic_map_points": len(result.cloud),
        "octomap": result.octomap.summary() if result.octomap is not None else None,
        "rolling_shutter": result.rolling_shutter,
        "local_ba": result.local_ba,
        "loop_closing": result.loop_closing,
        "loop_closures": len(result.loop_closures),
        "loop_closure_frames": result.loop_closures,
        "loop_candidates_rejected": result.loop_candidates_rejected,
    }


def fmt(value: float | None, digits: int = 4) -> str:
    """A table cell: ``value`` with ``digits`` decimals, ``—`` for None or NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    return f"{value:.{digits}f}"


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def write_plots(
    folder: RunFolder,
    out: Path,
    evaluation: Evaluation,
    title: str,
    estimate: str = "estimate",
    repeats: Sequence[tuple[str, np.ndarray]] | None = None,
) -> list[str]:
    """Top view of the aligned estimate (labelled ``estimate``) vs ground truth
    (``trajectory.png``), ATE over time (``ate.png``) and, with ``repeats`` (label, aligned
    positions (N, 3) metres), every repeat in one top view (``repeats.png``); returns the file
    names (none without an ATE)."""
    if evaluation.ate is None:
        return []
    a = evaluation.ate
    with folder.placing(out / "trajectory.png") as path:
        plots.plot_trajectories(
            path,
            a.gt_positions,
            [(estimate, a.est_positions)],
            f"{title}: trajectory ({a.stats.pairs} poses, aligned)",
        )
    with folder.placing(out / "ate.png") as path:
        plots.plot_error_over_time(path, a.stamps, a.errors, f"{title}: absolute trajectory error")
    names = ["trajectory.png", "ate.png"]
    if repeats is not None:
        with folder.placing(out / "repeats.png") as path:
            plots.plot_trajectories(
                path, a.gt_positions, list(repeats), f"{title}: every repeat (aligned)"
            )
        names.append("repeats.png")
    return names


def error_table_md(data: dict[str, Any]) -> list[str]:
    """The trajectory-error table of ``report.md`` from the :func:`~.evaluation.scores_dict`
    keys of ``data`` (or why there is none)."""
    if data["ate"] is None:
        return [f"Not evaluated: {data['ate_error']}", ""]
    ate = data["ate"]
    lines = [
        "| | RMSE | Mean | Median | S.D. | Min | Max | pairs |",
        "|---|---|---|---|---|---|---|---|",
        "| ATE [m] | " + " | ".join(fmt(ate[k]) for k in STAT_KEYS) + f" | {ate['pairs']} |",
    ]
    for key in ("rpe", "rpe_1s"):
        rpe = data.get(key)
        if rpe is None:
            continue
        unit = f"{rpe['delta']:g} {rpe['unit']}"
        for part, label, digits in (("trans", "trans [m]", 4), ("rot_deg", "rot [deg]", 3)):
            lines.append(
                f"| RPE {label} / {unit} | "
                + " | ".join(fmt(rpe[part][k], digits) for k in STAT_KEYS)
                + f" | {rpe[part]['pairs']} |"
            )
    out = [
        *lines,
        "",
        f"Alignment: {data['evaluation']['align']}; association max difference "
        f"{data['evaluation']['max_diff']} s.",
        "",
    ]
    bands = data.get("ate_bands")
    if bands:
        out += [
            f"Of the ATE RMSE, {fmt(bands['slow'])} m is slow (the error averaged over "
            f"{bands['window_s']:g} s: drift a back end can correct) and {fmt(bands['fast'])} m "
            "fast (per-frame jitter).",
            "",
        ]
    return out


def write_report(
    folder: RunFolder,
    out: Path,
    data: dict[str, Any],
    evaluation: Evaluation,
    *,
    heading: str,
    summary: Sequence[str],
    sections: Sequence[str] = (),
    error_heading: str = "Trajectory error",
    estimate: str = "estimate",
    repeats: Sequence[tuple[str, np.ndarray]] | None = None,
) -> list[str]:
    """Write ``metrics.json`` (``data``), the plots of :func:`write_plots` and ``report.md`` into
    ``out``, each file atomically through ``folder``; returns the plot names.

    ``report.md``: ``# heading``, the ``summary`` lines, ``## error_heading`` with
    :func:`error_table_md`, the system's ``sections`` (Markdown lines), then the plots.
    """
    folder.write_text(
        out / "metrics.json", json.dumps(data, indent=2, default=_json_default) + "\n"
    )
    title = Path(data["sequence"]).name
    figures = write_plots(folder, out, evaluation, title, estimate, repeats)
    lines = [f"# {heading}", "", *summary, "", f"## {error_heading}", "", *error_table_md(data)]
    lines += sections
    for figure in figures:
        lines += [f"![{figure}]({figure})", ""]
    folder.write_text(out / "report.md", "\n".join(lines))
    return figures


def write_run(
    out_dir: StrPath,
    result: RunResult,
    evaluation: Evaluation,
    config: EvalConfig,
    settings: dict[str, Any] | None = None,
    folder: RunFolder | None = None,
    repeats: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write every output of one harness run into ``out_dir``, each file atomically; returns the
    metrics dictionary. ``folder``: the run folder (inside which ``out_dir`` lies) that records
    the files for its manifest; None writes without one. ``repeats``: for the median run of
    repeated runs, the keys of :func:`~.repeats.repeats_metrics` (added to ``metrics.json`` and
    the report)."""
    out = Path(out_dir)
    folder = folder or RunFolder(out)
    with folder.writing(out / "trajectory.txt") as tmp:
        write_trajectory(
            tmp,
            result.trajectory,
            comment=f"uss-slam estimate, filters={result.filters}, camera-to-world",
        )
    data = metrics_dict(result, evaluation, config)
    if repeats is not None:
        data.update(repeats)
    if settings is not None:
        data["settings"] = settings
    with folder.writing(out / "map.ply") as tmp:
        write_ply(tmp, result.cloud)
    if result.octomap is not None:
        with folder.writing(out / "octomap.ot") as tmp:
            result.octomap.write(tmp)
    write_report(
        folder,
        out,
        data,
        evaluation,
        heading=f"uss-slam run: {Path(result.sequence).name}",
        summary=_summary_md(result),
        sections=_sections_md(result, data),
    )
    return data


def _summary_md(result: RunResult) -> list[str]:
    filters = ", ".join(result.filters) or "none (baseline)"
    return [
        f"- sequence: `{result.sequence}`",
        f"- camera: {result.camera}",
        f"- segmenter: {result.segmenter}; filters: {filters}",
        f"- frames: {result.frames} processed, {result.tracked} tracked "
        f"({100 * result.tracked_fraction:.1f}%), {result.unmatched_rgb} colour frames without "
        "depth partner skipped",
        f"- keyframes: {result.keyframes}; map points: {result.map_points} "
        f"({result.culled_points} culled); relocalisations: {result.relocalisations} "
        f"after {result.lost_events} tracking losses",
    ]


def _sections_md(result: RunResult, data: dict[str, Any]) -> list[str]:
    """The harness's sections of ``report.md``: keypoints, time, maps, back end."""
    kp = result.keypoints
    lines = [
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
    where = {
        "prefetch": "in the prefetch threads, concurrently with ORB extraction",
        "semantic": "in a semantic thread off the tracking path, masks carried between",
    }.get(seg["thread"], "in the main thread")
    schedule = "every frame" if seg["schedule"] == "every_frame" else "keyframes only"
    lines += [
        "",
        f"{result.fps:.1f} frames/s end to end; pipeline / ORB extraction time = {fmt(ratio, 2)}.",
        "",
        f"Segmentation ({result.segmenter}, {schedule}, {where}): {seg['frames_segmented']} of "
        f"{result.frames} frames segmented, {fmt(seg['wall_ms'], 2)} ms wall / "
        f"{fmt(seg['cpu_ms'], 2)} ms CPU per segmented frame; ORB extraction "
        f"{seg['orb_wall_ms']:.2f} ms wall / {seg['orb_cpu_ms']:.2f} ms CPU per frame.",
        "",
        f"Semantic map: `map.ply`, {len(result.cloud)} points.",
        "",
    ]
    shutter = result.rolling_shutter
    if shutter.get("readout"):
        lines += [
            f"Rolling shutter: keypoints of {shutter['frames_corrected']} frames moved to their "
            f"stamp for a {1000 * float(shutter['readout']):g} ms readout "
            f"(from {shutter['readout_from']}).",
            "",
        ]
    elif shutter:
        lines += [f"Rolling shutter: no correction ({shutter['readout_from']}).", ""]
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
    lines += repeats_md(data)
    lines += _backend_md(result)
    return lines


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
        if "depth_noise" in ba:
            k = float(ba["depth_noise"])
            model = f"σ_z = {k:g}·z²" if k > 0 else "ORB-SLAM2's (u, v, u_r) of equal sigma"
            lines.append(f"Depth noise model: {model}, from {ba['depth_noise_from']}.")
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
        cells = [fmt(v, digits) for v in values] + [
            "—" if g is None else f"{g:.1f}%" for g in gains
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    for label, key, digits in (
        ("tracked fraction", "tracked_fraction", 3),
        ("frames/s", "fps", 1),
    ):
        values = [runs[n][key] for n in names]
        table[label] = dict(zip(names, values, strict=True))
        cells = [label, *(fmt(v, digits) for v in values), *([""] * (len(names) - 1))]
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

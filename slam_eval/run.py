"""``uss-slam``: the Hydra entry point of the SLAM evaluation harness (``configs/slam_eval.yaml``).

Glue only: compose the config, open the sequence, build segmenter / filters / pipeline, run, and
write the report (one run, or the baseline plus each filter set of ``compare``; each of them
``slam.repeats`` times, reported by its median run, :mod:`.scoring.repeats`).
"""

from __future__ import annotations

import logging
import sys
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from uss_slam.core.cli import hydra_task, run_hydra_app
from uss_slam.core.files import check_output_owner, check_writable, output_lock
from uss_slam.core.hydra_lines import typed_overrides
from uss_slam.core.paths import input_folder, naming
from uss_slam.core.schema import unused_settings

from .compare_sets import checked_runs
from .config import SlamEvalConfig, check, register_configs, removed_override, run_name
from .filters.build import build_filters
from .memory import check_slam_memory
from .scoring.evaluation import evaluate
from .scoring.repeats import (
    Perturbation,
    repeats_metrics,
    with_timing_of,
    write_repeat_trajectories,
)
from .scoring.report import metrics_dict, write_comparison, write_run
from .scoring.run_folder import RunFolder
from .segmenters.base import LabelsOnce, Segmenter, worth_keeping
from .sequence import MIN_STRIDED_FRAMES, TumSequence
from .systems.harness import SlamPipeline

log = logging.getLogger(__name__)
PROG = "uss-slam"

register_configs()  # the typed slam / eval defaults, before Hydra composes configs/slam_eval.yaml


def _own_hydra() -> Any:
    """Hydra's config when ``uss-slam`` runs as its own Hydra app; None when it is not a Hydra
    app or runs composed inside another one (``uss-experiments``' jobs), whose job directory
    and records are that app's, not this run's."""
    if not HydraConfig.initialized():
        return None
    hydra_cfg = HydraConfig.get()
    return hydra_cfg if hydra_cfg.job.config_name == "slam_eval" else None


def output_dir(cfg: DictConfig) -> Path:
    """Hydra's job directory (``out_dir``, or its numbered sub-folder in a multirun); ``out_dir``
    itself when ``uss-slam`` runs inside another app."""
    hydra_cfg = _own_hydra()
    return Path(hydra_cfg.runtime.output_dir) if hydra_cfg is not None else Path(str(cfg.out_dir))


def _write_hydra_files(folder: RunFolder, cfg: DictConfig) -> list[str]:
    """``.hydra/config.yaml``, ``hydra.yaml`` and ``overrides.yaml`` as Hydra writes them (its
    ``output_subdir`` is off so that they appear only with a finished run's outputs)."""
    hydra_cfg = _own_hydra()
    if hydra_cfg is None:
        return []
    folder.write_text(".hydra/config.yaml", OmegaConf.to_yaml(cfg))
    folder.write_text(
        ".hydra/hydra.yaml", OmegaConf.to_yaml(OmegaConf.create({"hydra": hydra_cfg}))
    )
    overrides = OmegaConf.to_container(hydra_cfg.overrides.task)
    folder.write_text(".hydra/overrides.yaml", OmegaConf.to_yaml(OmegaConf.create(overrides)))
    return [str(o) for o in overrides]


def _sequence(cfg: DictConfig, load_labels: bool) -> TumSequence:
    """The frames ``cfg.sequence`` selects (its lists read and checked; no image decoded)."""
    seq_cfg = cfg.sequence
    return TumSequence(
        str(seq_cfg.path),
        camera=seq_cfg.camera,
        max_diff=float(seq_cfg.max_diff),
        load_labels=load_labels,
        start=int(seq_cfg.start),
        stride=int(seq_cfg.stride),
        max_frames=None if seq_cfg.max_frames is None else int(seq_cfg.max_frames),
        min_strided_frames=MIN_STRIDED_FRAMES,
    )


def run(cfg: DictConfig) -> dict[str, Any]:
    """Run what ``cfg`` asks for; returns the metrics of the run (comparison: of the last run,
    with ``"comparison"`` holding every run's metrics).

    Everything is checked before the first frame is processed (config values, filters, segmenter,
    sequence, that ``out_dir`` is writable); ``out_dir`` is then locked against a second process
    (:func:`~uss_slam.core.files.output_lock`). The outputs replace an earlier run's in
    ``out_dir`` only once every SLAM run of the call has finished and its files are written (see
    :mod:`.scoring.run_folder`): a failure, Ctrl-C or a full disk before that, in a comparison
    too, leaves the earlier run as it was.
    """
    hydra_cfg = _own_hydra()
    overrides = [] if hydra_cfg is None else typed_overrides(hydra_cfg)
    # values first (a bad value is named before a missing folder); a variant's keys set in cfg
    plan = check(cfg, overrides)
    input_folder(str(cfg.sequence.path), "sequence.path", "expected a TUM RGB-D sequence folder")
    out = check_writable(output_dir(cfg), "out_dir")
    if _own_hydra() is not None:  # inside uss-experiments, its job folder is that app's
        check_output_owner(out, PROG, "out_dir")  # a uss-eval or uss-demo output, ...
    if OmegaConf.select(cfg, "system.name") == "orbslam3":  # the real ORB-SLAM3, not the harness
        from .systems.orbslam3.system import run_from_config

        # estimated as the harness is, before the first frame: one line if it cannot fit
        check_slam_memory(cfg, _sequence(cfg, load_labels=False), log)
        with output_lock(out, "out_dir"):
            return run_from_config(
                cfg,
                out,
                before_commit=lambda f: {"overrides": _write_hydra_files(f, cfg)},
                overrides=overrides,
            )
    plan = replace(plan, runs=checked_runs(cfg, plan.runs, plan.filter_params))
    model = cfg.segmenter.get("path")
    with naming("segmenter.path", str(model)) if model else nullcontext():  # its reader's line
        segmenter: Segmenter = hydra.utils.instantiate(cfg.segmenter)
    sequence = _sequence(cfg, load_labels=bool(getattr(segmenter, "needs_labels", False)))
    check_slam_memory(cfg, sequence, log)  # before the first frame: one line if it cannot fit
    warn_if_groundtruth_misses(sequence)
    warn_if_prefetch_mode_unused(cfg.slam)
    for line in unused_settings(cfg, SlamEvalConfig):
        print(f"{PROG}: warning: {line}", file=sys.stderr)
    with output_lock(out, "out_dir"):
        return _run_harness(cfg, plan, segmenter, sequence, out)


def _semantic_thread_settings(slam: DictConfig) -> dict[str, Any]:
    """The ``slam.*`` keys of :class:`SlamPipeline` that shape the map points on people: the
    provisional points and the semantic thread's carried mask (``segment=thread``)."""
    return dict(
        provisional_points=bool(slam.provisional_points),
        provisional_border_px=slam.provisional_border_px,
        semantic_nice=int(slam.semantic_nice),
        carry_to_keyframes=str(slam.carry_to_keyframes),
        carry_velocity=bool(slam.carry_velocity),
        carry_radius_m=slam.carry_radius_m,
        carry_radius_keypoints=str(slam.carry_radius_keypoints),
        carry_radius_min_inliers=int(slam.carry_radius_min_inliers),
        mask_refines_past=str(slam.mask_refines_past),
        mask_marks_projected=bool(slam.mask_marks_projected),
        mask_refits_keyframes=bool(slam.mask_refits_keyframes),
        mask_refit_min_observations=int(slam.mask_refit_min_observations),
        mask_max_age_s=slam.mask_max_age_s,
        final_ba=str(slam.final_ba),
    )


def _run_harness(
    cfg: DictConfig, plan: Any, segmenter: Segmenter, sequence: TumSequence, out: Path
) -> dict[str, Any]:
    """The harness's runs of :func:`run` (``out`` locked), their outputs committed together."""
    slam = cfg.slam
    settings = OmegaConf.to_container(cfg, resolve=True)

    def pipeline(names: list[str], repeat: Perturbation, labeller: Segmenter) -> SlamPipeline:
        return SlamPipeline(
            sequence,
            labeller,
            build_filters(names, plan.filter_params),
            orb=replace(plan.orb, n_features=repeat.n_features),
            tracker=plan.tracker,
            semantic_map=plan.semantic_map,
            prefetch=int(slam.prefetch),
            workers=int(slam.workers),
            reader_threads=slam.reader_threads,
            parallel=bool(slam.parallel),
            prefetch_mode=str(slam.prefetch_mode),
            **plan.backend,
            segment=str(cfg.segment),
            **_semantic_thread_settings(slam),
            progress=bool(cfg.progress),
            description=f"{sequence.path.name} [{run_name(names)}]"
            + (f" repeat {repeat.index}" if len(plan.repeats) > 1 else ""),
            sampling_seed=repeat.sampling_seed,
        )

    # Repeats of a filter set share one labeller: the segmenter runs once per frame, in repeat 0.
    reuse = len(plan.repeats) > 1 and bool(slam.reuse_labels) and worth_keeping(segmenter)

    pipelines = []
    for name, names in plan.runs:
        shared = LabelsOnce(segmenter) if reuse else segmenter
        pipelines.append((name, names, shared, [pipeline(names, r, shared) for r in plan.repeats]))
    folder: RunFolder | None = None
    results: dict[str, dict[str, Any]] = {}
    try:
        for name, names, shared, repeats in pipelines:
            done = []
            for repeat, job in zip(plan.repeats, repeats, strict=True):
                result = job.run()
                scores = evaluate(result.trajectory, sequence.groundtruth, plan.evaluation)
                done.append((result, scores, metrics_dict(result, scores, plan.evaluation)))
                if len(plan.repeats) > 1:
                    log.info(
                        "%s repeat %d: %s", run_name(names), repeat.index, _summary(done[-1][2])
                    )
            if folder is None:  # staged: the earlier run's outputs stay until the commit
                folder = RunFolder.start(out)
            run_dir = out if name is None else out / name
            extra = None
            median = 0
            if len(plan.repeats) > 1:
                paths = write_repeat_trajectories(run_dir, [d[0] for d in done], folder)
                extra = repeats_metrics([d[2] for d in done], plan.repeats, paths, reuse)
                median = extra["median_repeat"]
            result, scores, _ = done[median]
            if isinstance(shared, LabelsOnce):  # the time of the repeat that segmented
                result = with_timing_of(result, done[0][0])
                shared.forget()  # the filter set's repeats are done: its labels can go
            data = write_run(run_dir, result, scores, plan.evaluation, settings, folder, extra)
            results[run_name(names)] = data
            log.info("%s: %s -> %s", run_name(names), _summary(data), run_dir)
        assert folder is not None
        table = write_comparison(out, results, folder) if cfg.compare is not None else None
        overrides = _write_hydra_files(folder, cfg)
        folder.commit(sequence=str(sequence.path), runs=list(results), overrides=overrides)
    finally:
        if folder is not None:
            folder.discard()  # a run that did not commit: its staged files go
    if table is not None:
        print(table)
        return {**data, "comparison": results}
    return data


def warn_if_groundtruth_misses(sequence: TumSequence) -> None:
    """One warning line on stderr, before any work, when the sequence's ground truth shares no
    time span with its selected frames, or when the sequence has no ``groundtruth.txt`` (no
    pose to score against: ATE and RPE will be n/a). Not an error: the trajectory and map are
    still worth having."""
    gt = sequence.groundtruth
    frames = sequence.stamps
    if gt is None:
        print(
            f"{PROG}: warning: {sequence.path}: no groundtruth.txt, so ATE and RPE are n/a "
            "(the trajectory and the map are written)",
            file=sys.stderr,
        )
        return
    if not len(gt):
        print(
            f"{PROG}: warning: {sequence.path}/groundtruth.txt holds no pose, so ATE and RPE "
            "are n/a (the trajectory and the map are written)",
            file=sys.stderr,
        )
        return
    if not len(frames):
        return
    if gt.stamps.min() <= frames.max() and frames.min() <= gt.stamps.max():
        return
    print(
        f"{PROG}: warning: {gt.path}: the ground truth spans {gt.stamps.min():.3f}-"
        f"{gt.stamps.max():.3f} s, the frames {frames.min():.3f}-{frames.max():.3f} s: no time "
        "in common, so ATE and RPE are n/a",
        file=sys.stderr,
    )


def warn_if_prefetch_mode_unused(slam: DictConfig) -> None:
    """One warning line when ``slam.prefetch_mode=process`` would change nothing: without
    ``slam.parallel`` or with ``slam.prefetch=0`` nothing is prepared ahead, in any mode."""
    if str(slam.prefetch_mode) != "process":
        return
    off = [k for k, v in (("slam.parallel=false", not slam.parallel),
                          ("slam.prefetch=0", int(slam.prefetch) <= 0)) if v]  # fmt: skip
    if off:
        print(
            f"{PROG}: warning: slam.prefetch_mode=process does nothing with {' and '.join(off)} "
            "(the worker process needs slam.parallel=true and slam.prefetch > 0): frames are "
            "read and ORB-extracted in this process",
            file=sys.stderr,
        )


def _summary(data: dict[str, Any]) -> str:
    """One log line of a run's metrics (with the spread of its repeats, if any)."""
    ate = data["ate"]
    text = (
        f"ATE RMSE {'n/a' if ate is None else format(ate['rmse'], '.4f')} m, "
        f"tracked {100 * data['tracked_fraction']:.1f}%, {data['fps']:.1f} frames/s"
    )
    spread = data.get("ate_rmse_repeats")
    if spread is not None and spread["evaluated"]:
        text += (
            f" (median of {len(data['repeats'])} repeats; min {spread['min']:.4f}, "
            f"max {spread['max']:.4f})"
        )
    return text


@hydra.main(version_base="1.3", config_path="../configs", config_name="slam_eval")
def app(cfg: DictConfig) -> float | None:
    """The Hydra task; returns the ATE RMSE (metres) for sweepers, None if not evaluated."""
    data = hydra_task(PROG, run, cfg)
    if data is None:  # a multirun job that failed: the other jobs go on
        return None
    ate = data.get("ate")
    return None if ate is None else float(ate["rmse"])


def main() -> None:
    """``uss-slam``: the Hydra app, with the errors Hydra raises while composing the config (a
    wrong type, an unknown key or option, a folder it cannot create) as one line and exit code 1
    instead of Hydra's multi-line report. Internal errors keep their traceback."""
    removed = removed_override(sys.argv[1:])
    if removed is not None:  # Hydra would only say the key is unknown
        print(f"{PROG}: error: {removed}", file=sys.stderr)
        sys.exit(1)
    run_hydra_app(PROG, app)


if __name__ == "__main__":
    main()

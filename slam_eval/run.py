"""``uss-slam``: the Hydra entry point of the SLAM evaluation harness (``configs/slam_eval.yaml``).

Glue only: compose the config, open the sequence, build segmenter / filters / pipeline, run, and
write the report (one run, or the baseline plus each filter set of ``compare``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from uss_slam.core.cli import JobFailed, exit_on_user_error, run_hydra_app
from uss_slam.core.files import check_writable

from .config import check, register_configs, run_name
from .filters.dynamic import build_filters
from .scoring.report import evaluate, write_comparison, write_run
from .scoring.run_folder import RunFolder
from .segmenters.base import Segmenter
from .sequence import TumSequence
from .systems.harness import SlamPipeline

log = logging.getLogger(__name__)
PROG = "uss-slam"

register_configs()  # the typed slam / eval defaults, before Hydra composes configs/slam_eval.yaml


def output_dir(cfg: DictConfig) -> Path:
    """Hydra's job directory (``out_dir``, or its numbered sub-folder in a multirun)."""
    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.output_dir)
    return Path(str(cfg.out_dir))


def _write_hydra_files(folder: RunFolder, cfg: DictConfig) -> list[str]:
    """``.hydra/config.yaml``, ``hydra.yaml`` and ``overrides.yaml`` as Hydra writes them (its
    ``output_subdir`` is off so that they appear only with a finished run's outputs)."""
    if not HydraConfig.initialized():
        return []
    hydra_cfg = HydraConfig.get()
    folder.write_text(".hydra/config.yaml", OmegaConf.to_yaml(cfg))
    folder.write_text(
        ".hydra/hydra.yaml", OmegaConf.to_yaml(OmegaConf.create({"hydra": hydra_cfg}))
    )
    overrides = OmegaConf.to_container(hydra_cfg.overrides.task)
    folder.write_text(".hydra/overrides.yaml", OmegaConf.to_yaml(OmegaConf.create(overrides)))
    return [str(o) for o in overrides]


def run(cfg: DictConfig) -> dict[str, Any]:
    """Run what ``cfg`` asks for; returns the metrics of the run (comparison: of the last run,
    with ``"comparison"`` holding every run's metrics).

    Everything is checked before the first frame is processed (config values, filters, segmenter,
    sequence, that ``out_dir`` is writable); the outputs replace an earlier run's in ``out_dir``
    only once the first SLAM run has finished (see :mod:`.scoring.run_folder`).
    """
    plan = check(cfg)
    out = check_writable(output_dir(cfg), "out_dir")
    if OmegaConf.select(cfg, "system.name") == "orbslam3":  # the real ORB-SLAM3, not the harness
        from .systems.orbslam3.system import run_from_config

        return run_from_config(cfg, out)
    segmenter: Segmenter = hydra.utils.instantiate(cfg.segmenter)
    seq_cfg = cfg.sequence
    sequence = TumSequence(
        str(seq_cfg.path),
        camera=seq_cfg.camera,
        max_diff=float(seq_cfg.max_diff),
        load_labels=bool(getattr(segmenter, "needs_labels", False)),
        start=int(seq_cfg.start),
        stride=int(seq_cfg.stride),
        max_frames=None if seq_cfg.max_frames is None else int(seq_cfg.max_frames),
    )
    slam = cfg.slam
    settings = OmegaConf.to_container(cfg, resolve=True)
    pipelines = [
        (
            name,
            names,
            SlamPipeline(
                sequence,
                segmenter,
                build_filters(names, plan.filter_params),
                orb=plan.orb,
                tracker=plan.tracker,
                semantic_map=plan.semantic_map,
                prefetch=int(slam.prefetch),
                workers=int(slam.workers),
                parallel=bool(slam.parallel),
                **plan.backend,
                segment=str(cfg.segment),
                progress=bool(cfg.progress),
                description=f"{sequence.path.name} [{run_name(names)}]",
            ),
        )
        for name, names in plan.runs
    ]
    folder: RunFolder | None = None
    results: dict[str, dict[str, Any]] = {}
    for name, names, pipeline in pipelines:
        result = pipeline.run()
        scores = evaluate(result.trajectory, sequence.groundtruth, plan.evaluation)
        if folder is None:  # the earlier run's outputs go only now
            folder = RunFolder.start(out)
        run_dir = out if name is None else out / name
        data = write_run(run_dir, result, scores, plan.evaluation, settings, folder)
        results[run_name(names)] = data
        ate = data["ate"]
        log.info(
            "%s: ATE RMSE %s m, tracked %.1f%%, %.1f frames/s -> %s",
            run_name(names),
            "n/a" if ate is None else f"{ate['rmse']:.4f}",
            100 * data["tracked_fraction"],
            data["fps"],
            run_dir,
        )
    assert folder is not None
    table = write_comparison(out, results, folder) if cfg.compare is not None else None
    overrides = _write_hydra_files(folder, cfg)
    folder.commit(sequence=str(sequence.path), runs=list(results), overrides=overrides)
    if table is not None:
        print(table)
        return {**data, "comparison": results}
    return data


@hydra.main(version_base="1.3", config_path="../configs", config_name="slam_eval")
def app(cfg: DictConfig) -> float | None:
    """The Hydra task; returns the ATE RMSE (metres) for sweepers, None if not evaluated."""
    try:
        with exit_on_user_error(PROG, (OmegaConfBaseException,)):
            data = run(cfg)
    except JobFailed:  # a multirun job: printed and recorded, the other jobs go on
        return None
    ate = data.get("ate")
    return None if ate is None else float(ate["rmse"])


def main() -> None:
    """``uss-slam``: the Hydra app, with the errors Hydra raises while composing the config (a
    wrong type, an unknown key or option, a folder it cannot create) as one line and exit code 1
    instead of Hydra's multi-line report. Internal errors keep their traceback."""
    run_hydra_app(PROG, app)


if __name__ == "__main__":
    main()

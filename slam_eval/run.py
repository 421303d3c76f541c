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
from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from uss_slam.core.cli import exit_on_user_error
from uss_slam.core.errors import UssSlamError

from .filters import build_filters
from .frontend import OrbConfig
from .pipeline import SlamPipeline
from .report import EvalConfig, evaluate, write_comparison, write_run
from .segmenters import Segmenter
from .semantic_map import MapConfig
from .sequence import TumSequence
from .tracker import TrackerConfig

log = logging.getLogger(__name__)


def _dataclass(cls: type, section: Any, where: str) -> Any:
    values = OmegaConf.to_container(section, resolve=True) if section is not None else {}
    try:
        return cls(**(values or {}))
    except (TypeError, ValueError) as err:
        raise UssSlamError(f"{where}: {err}") from None


def _filter_sets(compare: Any) -> list[list[str]]:
    if not isinstance(compare, (list, ListConfig)) or not compare:
        raise UssSlamError(
            "compare must be a non-empty list of filter lists, e.g. "
            "compare=[[semantic],[semantic,geometry]]"
        )
    sets = []
    for item in compare:
        names = [str(item)] if isinstance(item, str) else [str(n) for n in item]
        sets.append(names)
    return sets


def _run_name(filters: list[str]) -> str:
    return "+".join(filters) if filters else "baseline"


def output_dir(cfg: DictConfig) -> Path:
    """Hydra's job directory (``out_dir``, or its numbered sub-folder in a multirun)."""
    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.output_dir)
    return Path(str(cfg.out_dir))


def run(cfg: DictConfig) -> dict[str, Any]:
    """Run what ``cfg`` asks for; returns the metrics of the run (comparison: of the last run,
    with ``"comparison"`` holding every run's metrics)."""
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
    orb = _dataclass(OrbConfig, slam.orb, "slam.orb")
    tracker = _dataclass(TrackerConfig, slam.tracker, "slam.tracker")
    semantic_map = _dataclass(MapConfig, slam.map, "slam.map")
    evaluation = _dataclass(EvalConfig, cfg.eval, "eval")
    params = OmegaConf.to_container(slam.filter_params, resolve=True) or {}
    settings = OmegaConf.to_container(cfg, resolve=True)
    out = output_dir(cfg)

    if cfg.compare is None:
        runs = [(None, [str(f) for f in cfg.filters])]
    else:
        runs = [("baseline", [])] + [(_run_name(s), s) for s in _filter_sets(cfg.compare)]
    results: dict[str, dict[str, Any]] = {}
    for name, names in runs:
        filters = build_filters(names, params)
        pipeline = SlamPipeline(
            sequence,
            segmenter,
            filters,
            orb=orb,
            tracker=tracker,
            semantic_map=semantic_map,
            prefetch=int(slam.prefetch),
            workers=int(slam.workers),
            parallel=bool(slam.parallel),
            segment=str(cfg.segment),
            progress=bool(cfg.progress),
            description=f"{sequence.path.name} [{_run_name(names)}]",
        )
        result = pipeline.run()
        scores = evaluate(result.trajectory, sequence.groundtruth, evaluation)
        run_dir = out if name is None else out / name
        data = write_run(run_dir, result, scores, evaluation, settings)
        results[_run_name(names)] = data
        ate = data["ate"]
        log.info(
            "%s: ATE RMSE %s m, tracked %.1f%%, %.1f frames/s -> %s",
            _run_name(names),
            "n/a" if ate is None else f"{ate['rmse']:.4f}",
            100 * data["tracked_fraction"],
            data["fps"],
            run_dir,
        )
    if cfg.compare is not None:
        table = write_comparison(out, results)
        print(table)
        return {**data, "comparison": results}
    return data


@hydra.main(version_base="1.3", config_path="../configs", config_name="slam_eval")
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns the ATE RMSE (metres) for sweepers, None if not evaluated."""
    with exit_on_user_error("uss-slam", (OmegaConfBaseException,)):
        data = run(cfg)
    ate = data.get("ate")
    return None if ate is None else float(ate["rmse"])


if __name__ == "__main__":
    main()

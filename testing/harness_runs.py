"""Harness runs on synthetic sequences as the SLAM benchmarks and studies measure them:
sequences rendered on first use, the back-end variants (``benchmarks/slam_backend.py``), one run's
figures and the median of runs perturbed as ``uss-slam slam.repeats``."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from uss_slam.core.tum_io import Trajectory
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import OrbConfig
from uss_slam.slam_eval.mapping.local_mapping import LocalMappingConfig
from uss_slam.slam_eval.scoring.evaluation import BANDS_WINDOW
from uss_slam.slam_eval.scoring.metrics import ate, ate_bands
from uss_slam.slam_eval.scoring.repeats import Perturbation, median_index, perturbations
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.tracker import TrackerConfig
from uss_slam.synthetic import render_sequence
from uss_slam.synthetic.styles import DEPTH_NOISE_K

WALKING = ("walking_xyz", "walking_rpy", "walking_halfsphere")
"""The walking presets (the targets' ``--presets`` default, with ``static_xyz``)."""


def sequence_path(data: Path, preset: str, frames: int, size: tuple[int, int], seed: int) -> Path:
    """The target-style sequence ``data/<preset>_<frames>_<W>x<H>_seed<seed>``, rendered
    (``uss-synth``) when it holds no ``rgb.txt`` yet."""
    path = data / f"{preset}_{frames}_{size[0]}x{size[1]}_seed{seed}"
    if not (path / "rgb.txt").is_file():
        print(f"rendering {path} ...", file=sys.stderr)
        render_sequence(path, preset=preset, frames=frames, size=size, seed=seed, progress=True)
    return path


def median_run(runs: list[dict]) -> dict:
    """The median run as ``slam.repeats`` chooses it (:func:`median_index`), with the ATE RMSE
    of every repeat."""
    rmses = [r["ate_rmse"] for r in runs]
    return {**runs[median_index(rmses)], "repeats": rmses}


VARIANTS = {
    "tracker": {},
    "local_ba": {"local_ba": True},
    "local_ba_orbslam2": {
        "local_ba": True,
        "local_ba_params": LocalMappingConfig(depth_noise=0.0),
    },
    "local_ba_sensor": {
        "local_ba": True,
        "local_ba_params": LocalMappingConfig(depth_noise=DEPTH_NOISE_K),
    },
    "loop": {"local_ba": True, "loop_closing": True},
    "loop_orbslam2": {
        "local_ba": True,
        "loop_closing": True,
        "local_ba_params": LocalMappingConfig(depth_noise=0.0),
    },
    "loop_only": {"loop_closing": True},
    "prosac": {"tracker": TrackerConfig(sampler="prosac")},
    "tracker_global_shutter": {"tracker": TrackerConfig(readout=0.0)},
    "loop_global_shutter": {
        "local_ba": True,
        "loop_closing": True,
        "tracker": TrackerConfig(readout=0.0),
    },
}


PREFETCH_MODULES = ("read", "orb", "segmentation")
"""Modules timed in the prefetch threads (the rest run in the main thread)."""


def _split_ate(seq: TumSequence, result) -> tuple[float | None, float | None]:
    """ATE RMSE of the keyframes' poses alone and of the other frames alone (each aligned on
    its own)."""
    keyframes = {e.stamp for e in result.log if e.keyframe}
    t = result.trajectory
    out = []
    for want in (True, False):
        sel = np.array([(s in keyframes) == want for s in t.stamps])
        if sel.sum() < 3:
            out.append(None)
            continue
        part = Trajectory(t.stamps[sel], t.positions[sel], t.quaternions[sel])
        out.append(ate(seq.groundtruth, part).stats.rmse)
    return out[0], out[1]


def run(path: Path, variant: str, filters: list[str], perturbation: Perturbation | None = None
        ) -> dict:  # fmt: skip
    """One run of the harness (oracle ``labels`` segmenter, ``filters``) under ``VARIANTS[variant]``
    on the sequence at ``path``: ATE RMSE (whole, keyframes, other frames, slow and fast parts),
    tracked fraction, frames/s, main-thread CPU ms per frame, local BA and loop-closure figures."""
    seq = TumSequence(path, load_labels=True)
    options = dict(VARIANTS[variant])
    if perturbation is not None:
        options["orb"] = OrbConfig(n_features=perturbation.n_features)
        options["sampling_seed"] = perturbation.sampling_seed
    result = SlamPipeline(
        seq, LabelsSegmenter(), build_filters(filters), progress=False, **options
    ).run()
    whole = ate(seq.groundtruth, result.trajectory)
    stats, bands = whole.stats, ate_bands(whole, BANDS_WINDOW)
    kf_ate, other_ate = _split_ate(seq, result)
    ba = result.local_ba or {}
    main_cpu = sum(ms for name, ms in result.cpu_ms.items() if name not in PREFETCH_MODULES)
    return {
        "ate_rmse": stats.rmse,
        "ate_keyframes": kf_ate,
        "ate_other_frames": other_ate,
        "ate_slow": bands.slow,
        "ate_fast": bands.fast,
        "tracked_fraction": result.tracked_fraction,
        "fps": result.fps,
        "main_cpu_ms": main_cpu,
        "keyframes": result.keyframes,
        "local_ba_ms": ba.get("wall_ms"),
        "local_ba_cpu_ms": (
            result.cpu_ms["local_ba"] * result.frames / ba["runs"] if ba.get("runs") else None
        ),
        "keyframes_culled": (result.local_ba or {}).get("keyframes_culled"),
        "loop_closures": [(c["frame"], c["loop_frame"]) for c in result.loop_closures],
    }


def run_cell(path: Path, variant: str, filters: list[str], repeats: int) -> dict:
    """One cell: a single run, or the median of ``repeats`` runs perturbed as ``slam.repeats``
    (repeat 0 as is, then ±1% feature budget and the RANSAC sampling seed)."""
    if repeats == 1:
        return run(path, variant, filters)
    cases = perturbations(repeats, 0, 0.01, OrbConfig().n_features)
    return median_run([run(path, variant, filters, p) for p in cases])

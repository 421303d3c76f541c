"""What do the SLAM harness's back end (local bundle adjustment, loop closing) and the PROSAC
sampler change against the tracker alone, in ATE RMSE and frames/s on synthetic sequences over
seeds? Reported in BENCHMARKS.md, "SLAM back end (local BA, loop closing, PROSAC)", and
docs/results/slam.md (its 2026-12-04 entries).

    python benchmarks/slam_backend.py --presets static_xyz walking_xyz --seeds 0 1 2 \\
        --frames 300 --size 640x480 --variants tracker local_ba local_ba_orbslam2 prosac
    python benchmarks/slam_backend.py --presets loop --frames 450 --variants tracker local_ba loop

Variants (all with the ``--filters`` given, default none):

- ``tracker``: no back end (the harness as before; reference of every ratio);
- ``local_ba``: local bundle adjustment + keyframe culling with the default parameters (the
  depth noise the sequence's ``intrinsics.yaml`` declares, else ORB-SLAM2's model);
- ``local_ba_orbslam2``: the same with ORB-SLAM2's isotropic stereo noise (``depth_noise=0``);
- ``local_ba_sensor``: local BA whose stereo factors model the synthetic sensor's depth noise
  (``depth_noise=0.0019``, the ``k`` of ``σ_z = k·z²`` the renderer's target style draws and
  declares);
- ``loop``: local BA and loop closing (the defaults); ``loop_orbslam2``: the same with
  ORB-SLAM2's depth model (``depth_noise=0``); ``loop_only``: loop closing without local BA;
- ``prosac``: the tracker alone with PROSAC sampling (``sampler=prosac``);
- ``tracker_global_shutter`` / ``loop_global_shutter``: ``tracker`` / ``loop`` without the
  rolling-shutter correction (``readout=0``; the others correct for the readout the sequence's
  ``intrinsics.yaml`` declares: the ``handheld_rpy`` preset's 30 ms).

``--repeats N`` runs each cell N times with the perturbations of ``uss-slam slam.repeats`` (±1%
feature budget, RANSAC sampling seed) and keeps the median run. Per run: ATE RMSE (SE(3)-aligned),
that of the keyframes only (their final poses) and of the other frames (composed on their
reference keyframes), its slow and fast parts (the error averaged over 0.5 s around each pose,
drift a keyframe back end can correct, and the per-frame jitter left; ``ate_bands`` in
``slam_eval.scoring.metrics``), tracked fraction, frames/s, the main thread's CPU ms per
frame (tracking, filters, mapping and the back end: robust to a busy machine, unlike frames/s),
the CPU ms per local BA and the loop closures; then per preset and variant the median over seeds
and its ratio to ``tracker``. The machine's load average is printed with the timings.
Sequences are rendered into ``--data`` on first use (uss-synth, target style) and reused.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from uss_slam.testing.harness_runs import VARIANTS, run_cell, sequence_path


def _local_ba_text(r: dict) -> str:
    """The local BA part of a run's line: its CPU and wall ms per run, or that it never ran (a
    sequence with one keyframe, e.g. a still camera), or nothing without local BA."""
    if r["local_ba_ms"] is None and r["local_ba_cpu_ms"] is None:
        return ""
    if r["local_ba_cpu_ms"] is None:
        return "  local BA never ran (one keyframe)"
    return f"  local BA {r['local_ba_cpu_ms']:.0f} ms CPU ({r['local_ba_ms']:.0f} wall)"


def _m(value: float | None) -> str:
    return "—" if value is None else f"{value:.4f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("outputs/bench/slam"))
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--size", default="640x480", help="WxH (default 640x480)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--presets", nargs="+", default=["static_xyz", "walking_xyz"])
    parser.add_argument("--variants", nargs="+", default=["tracker", "local_ba"])
    parser.add_argument("--filters", nargs="*", default=[], help="e.g. semantic")
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--repeats", type=int, default=1,
                        help="runs per cell, perturbed as slam.repeats (the median run is kept)")  # fmt: skip
    args = parser.parse_args()
    if args.repeats < 1:
        raise SystemExit(f"--repeats: must be >= 1, got {args.repeats}")
    unknown = [v for v in args.variants if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variant(s) {unknown}; choose from {', '.join(VARIANTS)}")
    size = tuple(int(v) for v in args.size.lower().split("x"))
    print(f"load average before: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)")
    results: dict[str, dict[str, list[dict]]] = {}
    start = time.perf_counter()
    for preset in args.presets:
        for seed in args.seeds:
            path = sequence_path(args.data, preset, args.frames, size, seed)
            for variant in args.variants:
                r = run_cell(path, variant, args.filters, args.repeats)
                r["seed"] = seed
                results.setdefault(preset, {}).setdefault(variant, []).append(r)
                ba = _local_ba_text(r)
                print(
                    f"{preset:14s} seed {seed} {variant:18s} ATE {r['ate_rmse']:.4f} m "
                    f"(keyframes {_m(r['ate_keyframes'])}, other frames {_m(r['ate_other_frames'])}; "
                    f"slow {_m(r['ate_slow'])}, fast {_m(r['ate_fast'])})"
                    "  tracked "
                    f"{r['tracked_fraction']:.2f}  {r['fps']:5.1f} frames/s  main thread "
                    f"{r['main_cpu_ms']:5.1f} ms CPU/frame  kf {r['keyframes']}{ba}  loops "
                    f"{r['loop_closures']}  (load {os.getloadavg()[0]:.1f})",
                    flush=True,
                )
    print(f"\nmedians over seeds {args.seeds} ({args.frames} frames, {args.size}, filters "
          f"{args.filters or 'none'}):")  # fmt: skip
    summary: dict[str, dict[str, dict]] = {}
    for preset, variants in results.items():
        ref = variants.get("tracker")
        ref_ate = statistics.median(r["ate_rmse"] for r in ref) if ref else None
        ref_cpu = statistics.median(r["main_cpu_ms"] for r in ref) if ref else None
        for variant, rows in variants.items():
            ate_m = statistics.median(r["ate_rmse"] for r in rows)
            fps_m = statistics.median(r["fps"] for r in rows)
            cpu_m = statistics.median(r["main_cpu_ms"] for r in rows)
            slow_m = statistics.median(r["ate_slow"] for r in rows)
            fast_m = statistics.median(r["ate_fast"] for r in rows)
            summary.setdefault(preset, {})[variant] = {
                "ate_rmse": ate_m,
                "ate_slow": slow_m,
                "ate_fast": fast_m,
                "fps": fps_m,
                "main_cpu_ms": cpu_m,
            }
            ratio = f"  ATE x{ate_m / ref_ate:.2f}  main CPU x{cpu_m / ref_cpu:.2f}" if ref else ""
            print(
                f"  {preset:14s} {variant:18s} ATE {ate_m:.4f} m (slow {slow_m:.4f}, fast "
                f"{fast_m:.4f})  {fps_m:5.1f} frames/s  "
                f"main thread {cpu_m:5.1f} ms CPU/frame{ratio}"
            )
    print(f"load average after: {os.getloadavg()[0]:.1f}; {time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.write_text(json.dumps({"runs": results, "medians": summary}, indent=2) + "\n")


if __name__ == "__main__":
    main()

"""What do frames/s, segmentation time and ATE become when the SLAM harness segments keyframes only
instead of every frame? Reported in BENCHMARKS.md, "SLAM harness" / "Segmentation schedule:
keyframes only vs every frame".

Segmentation is the slow stage (USS-SLAM: 0.31 s per frame on a GTX 1080). This script runs the
pipeline with the ``semantic`` filter under both schedules (``segment=every_frame``: every frame,
in the prefetch threads concurrently with ORB extraction; ``segment=keyframes``: keyframes only,
in the main thread) and reports for each: frames/s, segmentation ms per segmented frame, frames
segmented, and ATE RMSE.

Timing part (one sequence): a fake segmenter that costs a fixed time per call (``--delays``,
seconds; it sleeps, like a segmenter waiting for a GPU, then answers with the sequence's
ground-truth labels). Calls are serialised by a lock, as on one device; ``--concurrent`` lets
the prefetch workers' calls overlap (one device per worker). ``--onnx PATH`` also times an
exported model (:class:`~uss_slam.slam_eval.segmenters.onnx.OnnxSegmenter`, on the CPU here) under
both schedules, with the filter on its own labels. On a busy machine the wall-clock frames/s
say little; the column "CPU-bound, idle" gives the rate the run's measured CPU times (per
thread) and the segmenter's waiting allow on two otherwise idle cores (:func:`idle_rate`).

ATE part (``--ate-presets``, ``--seeds``): baseline (no filter) and the oracle ``labels``
segmenter under both schedules on each sequence; the labels do not depend on the delay, so the
ATE of a schedule is that of the oracle run (the timing part checks this: same trajectory).

    python benchmarks/slam_schedule.py --data outputs/bench/slam --frames 300 --delays 0.1 0.31
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import threading
import time
from pathlib import Path

import numpy as np

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
from uss_slam.slam_eval.sequence import Frame, TumSequence
from uss_slam.slam_eval.systems.harness import SEGMENT_SCHEDULES, RunResult, SlamPipeline
from uss_slam.testing.harness_runs import WALKING, sequence_path


class FixedCostSegmenter(LabelsSegmenter):
    """The oracle labels after ``delay`` seconds of waiting (a stand-in for GPU inference);
    with ``serial`` one call at a time (one device)."""

    def __init__(self, delay: float, serial: bool = True) -> None:
        self.delay = delay
        self.name = f"fixed-{1000 * delay:.0f}ms"
        self._lock = threading.Lock() if serial else None

    def segment(self, frame: Frame) -> np.ndarray:
        if self._lock is None:
            time.sleep(self.delay)
        else:
            with self._lock:
                time.sleep(self.delay)
        return super().segment(frame)


def run(path: Path, segmenter, filters: list[str], segment: str) -> tuple[RunResult, float]:
    seq = TumSequence(path, load_labels=segmenter.needs_labels)
    result = SlamPipeline(
        seq, segmenter, build_filters(filters), segment=segment, progress=False
    ).run()
    return result, ate(seq.groundtruth, result.trajectory).stats.rmse


WORKER_MODULES = ("read", "segmentation", "orb")


def idle_rate(result: RunResult, wait_ms: float, serial: bool, workers: int = 2) -> float:
    """Frames/s that the run's measured CPU times allow on two otherwise idle cores.

    ``wait_ms``: what one segmenter call costs without using a core (the fake segmenter sleeps;
    0 for segmenters that compute on the CPU, whose time is in the CPU ms already). Per frame
    the run needs at least: half the total CPU ms (two cores); the main thread's CPU ms, plus
    with the keyframes schedule its share of waiting (``wait_ms`` x segmented / frames); with
    every-frame segmentation, a prefetch worker's CPU ms plus ``wait_ms`` over ``workers``
    workers, and ``wait_ms`` itself when the calls are serialised (one device). The rate is
    1000 / the largest of these.
    """
    cpu = result.cpu_ms
    every = result.segment == "every_frame"
    names = [k for k in WORKER_MODULES if k != "segmentation" or every]
    worker = sum(cpu.get(k, 0.0) for k in names)
    main = sum(v for k, v in cpu.items() if k not in names)
    bounds = [(worker + main) / 2]
    if every:
        bounds.append((worker + wait_ms) / workers)
        if serial:
            bounds.append(wait_ms)
    else:
        main += wait_ms * result.segmented_frames / max(result.frames, 1)
    return 1000.0 / max(main, *bounds)


def row(
    label: str, schedule: str, result: RunResult, rmse: float, wait: float, serial: bool
) -> dict:
    seg = result.segmentation_ms.get("wall", 0.0)
    idle = idle_rate(result, wait, serial)
    out = {
        "segmenter": label,
        "schedule": schedule,
        "fps": result.fps,
        "fps_cpu_bound_idle": idle,
        "cpu_ms": result.cpu_ms,
        "segmentation_ms_per_segmented_frame": seg,
        "frames_segmented": result.segmented_frames,
        "frames": result.frames,
        "keyframes": result.keyframes,
        "ate_rmse": rmse,
        "tracked_fraction": result.tracked_fraction,
    }
    print(
        f"| {label} | {schedule} | {result.fps:.1f} | {idle:.1f} | {seg:.1f} | "
        f"{result.segmented_frames}/{result.frames} | {1000 * rmse:.1f} | "
        f"{result.tracked_fraction:.2f} |",
        flush=True,
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("outputs/bench/slam"))
    parser.add_argument("--preset", default="walking_xyz", help="sequence of the timing part")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--delays", type=float, nargs="*", default=[0.1, 0.31])
    parser.add_argument("--concurrent", action="store_true", help="fake calls may overlap")
    parser.add_argument("--onnx", type=Path, help="also time this exported segmenter")
    parser.add_argument("--onnx-threads", type=int, default=1, help="intra-op threads per call")
    parser.add_argument("--ate-presets", nargs="*", default=list(WALKING))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))
    start = time.perf_counter()
    results: dict[str, list[dict]] = {"timing": [], "ate": []}

    path = sequence_path(args.data, args.preset, args.frames, size, args.seeds[0])
    print(f"timing: {path.name}, filters [semantic], {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.2f}; fake calls "
          f"{'overlap' if args.concurrent else 'serialised (one device)'}")  # fmt: skip
    print("\n| segmenter | schedule | frames/s | frames/s CPU-bound, idle | seg. ms / segmented "
          "frame | frames segmented | ATE RMSE [mm] | tracked |\n|---|---|---|---|---|---|---|---|")  # fmt: skip
    serial = not args.concurrent
    segmenters: list[tuple[str, object, float]] = [("labels (0 ms)", LabelsSegmenter(), 0.0)]
    for delay in args.delays:
        label = f"fixed {1000 * delay:.0f} ms"
        segmenters.append((label, FixedCostSegmenter(delay, serial), 1000 * delay))
    if args.onnx:
        from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

        onnx = OnnxSegmenter(args.onnx, threads=args.onnx_threads)
        segmenters.append((f"onnx {args.onnx.name}", onnx, 0.0))
    reference: dict[str, RunResult] = {}
    for label, segmenter, wait in segmenters:
        for schedule in SEGMENT_SCHEDULES:
            result, rmse = run(path, segmenter, ["semantic"], schedule)
            results["timing"].append(row(label, schedule, result, rmse, wait, serial))
            if isinstance(segmenter, LabelsSegmenter):  # oracle labels: same run at any cost
                ref = reference.setdefault(schedule, result)
                same = np.array_equal(ref.trajectory.positions, result.trajectory.positions)
                if not same:
                    print(f"  note: {label} {schedule} trajectory differs from the 0 ms run")
    print(f"load average after the timing part: {os.getloadavg()[0]:.2f}")

    if args.ate_presets:
        print("\n| sequence | seed | baseline ATE [mm] | every_frame ATE [mm] | keyframes ATE "
              "[mm] | keyframes / every_frame | frames segmented (keyframes) |")  # fmt: skip
        print("|---|---|---|---|---|---|---|")
    for preset in args.ate_presets:
        for seed in args.seeds:
            path = sequence_path(args.data, preset, args.frames, size, seed)
            _, base = run(path, NoSegmenter(), [], "every_frame")
            every, every_rmse = run(path, LabelsSegmenter(), ["semantic"], "every_frame")
            kf, kf_rmse = run(path, LabelsSegmenter(), ["semantic"], "keyframes")
            results["ate"].append(
                {
                    "preset": preset,
                    "seed": seed,
                    "baseline": base,
                    "every_frame": every_rmse,
                    "keyframes": kf_rmse,
                    "frames_segmented_keyframes": kf.segmented_frames,
                    "frames": kf.frames,
                    "tracked_fraction": [every.tracked_fraction, kf.tracked_fraction],
                }
            )
            print(
                f"| {preset} | {seed} | {1000 * base:.1f} | {1000 * every_rmse:.1f} | "
                f"{1000 * kf_rmse:.1f} | {kf_rmse / every_rmse:.2f} | "
                f"{kf.segmented_frames}/{kf.frames} |",
                flush=True,
            )
    if results["ate"]:
        ratios = [r["keyframes"] / r["every_frame"] for r in results["ate"]]
        print(f"median keyframes / every_frame ATE ratio: {statistics.median(ratios):.2f}")
    print(f"total {time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()

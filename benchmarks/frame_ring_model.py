"""How many frames should the frame reader process's ring hold (``slam.prefetch_mode=process``)?

The main thread's work comes in bursts (local BA and loop closing after a new keyframe), the
worker's is steady. One run in process mode records each frame's main-thread CPU time (the
frame loop's step) and the worker process's CPU time per frame; a model of two idle cores then
replays them: the worker prepares frame ``i`` once it has prepared frame ``i - 1`` and a slot is
free (the main thread has started frame ``i - ring``), the main thread starts frame ``i`` once it
is ready and frame ``i - 1`` is done. Printed: the frame rate the model gives for each ring
size. A model, not a measurement: it leaves out the main process's prefetch threads (they copy
frames out of the ring and read depth images, up to ``prefetch`` frames ahead) and the cores'
other users; run on a busy machine, CPU times grow with the load. Reported in BENCHMARKS.md,
"SLAM harness speed".

    python benchmarks/frame_ring_model.py --data outputs/bench/slam/walking_xyz_300_640x480_seed0
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend import process as frontend_process
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems import frame_loop
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.testing.machine import cpu_model

RINGS = (2, 4, 8, 16, 24, 32, 64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--data", type=Path, required=True, help="a TUM-layout sequence folder")
    args = parser.parse_args()
    main_ms, worker_ms, fps = record(args.data)
    print(f"{args.data}: {len(main_ms)} frames, {cpu_model()}, load average "
          f"{os.getloadavg()[0]:.2f}; the run: {fps:.1f} frames/s")  # fmt: skip
    print(f"main thread CPU ms per frame: mean {main_ms.mean():.1f}, median "
          f"{np.median(main_ms):.1f}, 90th percentile {np.percentile(main_ms, 90):.1f}, "
          f"max {main_ms.max():.1f}; worker process {worker_ms:.1f} per frame")  # fmt: skip
    steady = np.full(len(main_ms), worker_ms)
    print("model, frames/s by ring size: " + ", ".join(
        f"{ring} {replay(steady, main_ms, ring):.1f}" for ring in RINGS))  # fmt: skip


def record(path: Path) -> tuple[np.ndarray, float, float]:
    """One process-mode run (``semantic``, back end on): ``(N,)`` main-thread CPU ms per frame,
    the worker process's mean CPU ms per frame and the run's frames/s."""
    steps: list[float] = []
    step = frame_loop.FrameLoop.step

    def timed(self, *args, **kwargs):
        start = time.thread_time()
        out = step(self, *args, **kwargs)
        steps.append(1000.0 * (time.thread_time() - start))
        return out

    workers = []
    start = frontend_process.start

    def recording(*args, **kwargs):
        workers.append(start(*args, **kwargs))
        return workers[-1]

    seq = TumSequence(path, load_labels=True)
    pipeline = SlamPipeline(seq, LabelsSegmenter(), build_filters(["semantic"]), progress=False,
                            local_ba=True, loop_closing=True, prefetch_mode="process")  # fmt: skip
    frame_loop.FrameLoop.step, frontend_process.start = timed, recording
    try:
        result = pipeline.run()
    finally:
        frame_loop.FrameLoop.step, frontend_process.start = step, start
    worker_ms = 1000.0 * sum(w.worker_cpu for w in workers if w is not None) / len(steps)
    return np.array(steps), worker_ms, result.fps


def replay(worker_ms: np.ndarray, main_ms: np.ndarray, ring: int) -> float:
    """Frames/s of the two-core model (module docstring) for per-frame ``(N,)`` CPU ms."""
    n = len(main_ms)
    started, done = np.zeros(n), np.zeros(n)
    ready = 0.0
    for i in range(n):
        ready = (ready if i < ring else max(ready, started[i - ring])) + worker_ms[i]
        started[i] = max(ready, done[i - 1] if i else 0.0)
        done[i] = started[i] + main_ms[i]
    return 1000.0 * n / done[-1]


if __name__ == "__main__":
    main()

"""Does the SLAM harness run at >= 25 frames/s at 640x480 with the ``semantic`` filter on 2 cores,
and what is its ratio to ORB extraction alone, measured in the same run? Reported in BENCHMARKS.md,
"SLAM harness" / "Speed" (with the back end on: "SLAM back end (local BA, loop closing, PROSAC)").

Each repeat runs the whole pipeline (PNG decoding, oracle segmentation and ORB in two prefetch
threads; filter, tracking, mapping in the main thread) over the sequence, then times ORB
extraction alone on the same frames held in memory. Reported: median frames/s, median wall and
CPU ms per frame of each module, pipeline ms/frame ÷ ORB-only ms/frame (a ratio survives a busy
machine better than absolute time), and the frame rate the measured CPU times allow on two idle
cores (the machine this runs on is shared: its load average is printed).

    python benchmarks/slam_speed.py --data outputs/bench/slam --frames 300 --repeats 3
    python benchmarks/slam_speed.py --filters --local-ba --loop-closing   # the back end on
    python benchmarks/slam_speed.py --local-ba --loop-closing --orbslam3 vocab.txt

``--orbslam3 VOCAB`` also runs the real ORB-SLAM3 on the same frames in the same command
(``uss-slam system=orbslam3 system.repeats=--repeats system.realtime=false``: as fast as it
tracks, unfiltered, after the harness's repeats)
and prints its median frames/s (frame reading and tracking, its own local-mapping and
loop-closing threads beside) and the harness's ratio to it.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.testing.harness_runs import sequence_path


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0].replace("\n", " "),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/bench/slam"),
                        help="folder of rendered sequences (rendered there on first use)")  # fmt: skip
    parser.add_argument("--preset", default="walking_xyz", help="uss-synth preset (seed 0)")
    parser.add_argument("--frames", type=int, default=300, help="frames of the sequence")
    parser.add_argument("--size", default="640x480", help="WxH")
    parser.add_argument("--repeats", type=int, default=3, help="whole-pipeline runs (median)")
    parser.add_argument("--filters", nargs="*", default=["semantic"],
                        help="dynamic filters (oracle labels); give none for no filter")  # fmt: skip
    parser.add_argument("--local-ba", action="store_true",
                        help="local BA on (uss-slam's default; this benchmark's pipeline "
                             "runs the tracker alone without it)")  # fmt: skip
    parser.add_argument("--loop-closing", action="store_true",
                        help="loop closing on (uss-slam's default, as --local-ba)")  # fmt: skip
    parser.add_argument(
        "--orbslam3", type=Path, metavar="VOCAB", help="also time ORB-SLAM3 with this vocabulary"
    )
    args = parser.parse_args()
    if args.orbslam3 is not None and not args.orbslam3.is_file():
        raise SystemExit(f"--orbslam3: {args.orbslam3} is not a file (uss-vocab build makes one)")
    size = tuple(int(v) for v in args.size.lower().split("x"))
    path = sequence_path(args.data, args.preset, args.frames, size, 0)
    seq = TumSequence(path, load_labels=True)
    frames = [seq.load(i) for i in range(len(seq))]
    extractor = OrbExtractor(OrbConfig(), seq.camera)
    print(f"{path}: {len(seq)} frames {size[0]}x{size[1]}, filters {args.filters}, local BA "
          f"{args.local_ba}, loop closing {args.loop_closing}, {os.cpu_count()} CPUs "
          f"({cpu_model()}), load average {os.getloadavg()[0]:.2f}")  # fmt: skip

    fps, ratios, own_ratios, modules, cpus, bounds = [], [], [], [], [], []
    worker_modules = {"read", "segmentation", "orb"}
    for repeat in range(args.repeats):
        result = SlamPipeline(
            seq,
            LabelsSegmenter(),
            build_filters(args.filters),
            progress=False,
            local_ba=args.local_ba,
            loop_closing=args.loop_closing,
        ).run()
        start = time.perf_counter()
        for frame in frames:
            extractor(frame.gray, frame.depth)
        orb_only = 1000.0 * (time.perf_counter() - start) / len(frames)
        total = result.timing_ms["total"]
        fps.append(result.fps)
        ratios.append(total / orb_only)
        own_ratios.append(total / result.timing_ms["orb"])
        modules.append(result.timing_ms)
        cpus.append(result.cpu_ms)
        worker = sum(v for k, v in result.cpu_ms.items() if k in worker_modules)
        main_thread = sum(v for k, v in result.cpu_ms.items() if k not in worker_modules)
        # Two prefetch workers and the main thread share the two cores: per frame at least
        # half the total CPU time, and at least the main thread's own (it is sequential).
        bounds.append(1000.0 / max(main_thread, (worker + main_thread) / 2))
        print(
            f"  CPU ms/frame: prefetch workers {worker:.1f} (read+segmentation+orb), main thread "
            f"{main_thread:.1f} (filters+tracking+mapping) -> CPU-bound rate on 2 idle cores "
            f"{bounds[-1]:.1f} frames/s"
        )
        print(
            f"repeat {repeat}: {result.fps:5.1f} frames/s, pipeline {total:.1f} ms/frame, "
            f"ORB alone {orb_only:.1f} ms/frame -> ratio {total / orb_only:.2f} "
            f"(tracked {result.tracked_fraction:.2f}, ATE RMSE "
            f"{ate(seq.groundtruth, result.trajectory).stats.rmse:.6f} m)",
            flush=True,
        )
    print(f"median: {statistics.median(fps):.1f} frames/s; pipeline / ORB-only "
          f"{statistics.median(ratios):.2f}; pipeline / ORB inside the run "
          f"{statistics.median(own_ratios):.2f}")  # fmt: skip
    names = list(modules[0])
    print("median ms per frame: " + ", ".join(
        f"{n} {statistics.median(m.get(n, 0.0) for m in modules):.2f}" for n in names))  # fmt: skip
    print("median CPU ms per frame: " + ", ".join(
        f"{n} {statistics.median(c.get(n, 0.0) for c in cpus):.2f}" for n in cpus[0]))  # fmt: skip
    print(f"median CPU-bound rate on 2 idle cores: {statistics.median(bounds):.1f} frames/s")
    if args.orbslam3 is not None:
        orb3 = orbslam3_fps(path, args.orbslam3, args.repeats)
        print(f"ORB-SLAM3, same frames, no filter: median {statistics.median(orb3):.1f} frames/s "
              f"(repeats {', '.join(f'{v:.1f}' for v in orb3)}); harness / ORB-SLAM3 "
              f"{statistics.median(fps) / statistics.median(orb3):.2f}")  # fmt: skip
    print(f"load average after: {os.getloadavg()[0]:.2f}")


def cpu_model() -> str:
    """The CPU's model name as ``lscpu`` prints it (``/proc/cpuinfo``), or ``unknown CPU``."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def orbslam3_fps(path: Path, vocabulary: Path, repeats: int) -> list[float]:
    """Frames/s of each ORB-SLAM3 repeat on ``path`` (``uss-slam system=orbslam3``)."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            sys.executable, "-m", "uss_slam.slam_eval.run", "system=orbslam3",
            f"sequence.path={path}", f"system.vocabulary={vocabulary.resolve()}",
            f"system.repeats={repeats}", "system.realtime=false", f"out_dir={tmp}/orbslam3",
        ]  # fmt: skip
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f"ORB-SLAM3 failed ({done.returncode}): {done.stderr.strip()[-400:]}")
        metrics = json.loads(Path(tmp, "orbslam3", "metrics.json").read_text())
    return [r["fps"] for r in metrics["repeats"]]


if __name__ == "__main__":
    main()

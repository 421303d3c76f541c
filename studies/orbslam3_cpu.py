"""How much CPU does ORB-SLAM3 use per frame on the SLAM speed benchmark's sequence, with the
frames read as its ``uss-slam system=orbslam3`` worker reads them and with them held in memory?
Reported in BENCHMARKS.md, "SLAM harness speed" (where the time goes).

One process per setting (ORB-SLAM3 keeps static state): ``read`` feeds ``track_rgbd`` from
``TumSequence.frames()`` (the harness's reader, PNG decoding in a prefetch thread, as the
worker's timed loop does), ``memory`` from frames loaded beforehand. Printed: frames/s, the
process's CPU ms per frame over the tracking loop (every thread: its tracking, local-mapping
and loop-closing threads and the reader) and the tracking thread's own. The harness's figures
come from ``benchmarks/slam_speed.py`` on the same sequence.

    python studies/orbslam3_cpu.py outputs/bench/slam/walking_xyz_300_640x480_seed0 vocab.txt
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("sequence", type=Path, help="a TUM RGB-D sequence folder")
    parser.add_argument("vocabulary", type=Path, help="a DBoW2 text vocabulary (uss-vocab build)")
    parser.add_argument("--repeats", type=int, default=1, help="runs per setting, in turns")
    parser.add_argument("--one", choices=("read", "memory"), help=argparse.SUPPRESS)
    parser.add_argument("--settings", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one is not None:
        track(args.sequence, args.vocabulary, args.settings, args.one)
        return
    with tempfile.TemporaryDirectory() as tmp:
        settings = Path(tmp, "orbslam3.yaml")
        write_settings(args.sequence, settings)
        print(f"{args.sequence}, load average {os.getloadavg()[0]:.2f}", flush=True)
        for _ in range(args.repeats):
            for how in ("read", "memory"):
                cmd = [sys.executable, __file__, str(args.sequence), str(args.vocabulary),
                       "--one", how, "--settings", str(settings)]  # fmt: skip
                done = subprocess.run(cmd, capture_output=True, text=True, check=True)
                print([ln for ln in done.stdout.splitlines() if ln.startswith(how)][-1])
        print(f"load average after: {os.getloadavg()[0]:.2f}")


def write_settings(sequence: Path, out: Path) -> None:
    """ORB-SLAM3's settings for ``sequence``, as ``uss-slam system=orbslam3`` writes them."""
    from uss_slam.slam_eval.sequence import TumSequence
    from uss_slam.slam_eval.systems.orbslam3.config import OrbSlam3Config
    from uss_slam.slam_eval.systems.orbslam3.settings import frame_rate, settings_yaml

    seq = TumSequence(sequence)
    out.write_text(settings_yaml(seq.camera, OrbSlam3Config(), frame_rate(seq.stamps)))


def track(sequence: Path, vocabulary: Path, settings: Path, how: str) -> None:
    """Every frame through ORB-SLAM3 in this process; one line of figures."""
    import pyorbslam3

    from uss_slam.slam_eval.sequence import TumSequence

    seq = TumSequence(sequence)
    slam = pyorbslam3.Slam(str(vocabulary), str(settings), pyorbslam3.Sensor.RGBD)
    held = [seq.load(i) for i in range(len(seq))] if how == "memory" else None
    frames = iter(held) if held is not None else seq.frames()
    cpu, wall, thread = time.process_time(), time.perf_counter(), time.thread_time()
    for frame in frames:
        slam.track_rgbd(frame.rgb, frame.depth, frame.stamp)
    n = len(seq)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    thread = time.thread_time() - thread
    print(f"{how}: {n / wall:.1f} frames/s, process {1000 * cpu / n:.1f} CPU ms/frame, tracking "
          f"thread {1000 * thread / n:.1f} (load {os.getloadavg()[0]:.2f})", flush=True)  # fmt: skip
    slam.shutdown()


if __name__ == "__main__":
    main()

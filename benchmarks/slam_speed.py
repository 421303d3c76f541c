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

``--prefetch-mode both`` (the default) runs every repeat twice, in turns, with frames read and
ORB-extracted in this process's threads (``slam.prefetch_mode=thread``) and in a worker process
(``process``; the first such run also starts Python's fork server), and prints the frame-rate
ratio of each pair beside the CPU milliseconds per frame of the main thread, of this process and
of the worker process.

``--prefetch-mode defaults`` compares the default before 2026-12-07 (``before``: the threads,
with OpenBLAS's and OpenCV's thread pools as loaded) with today's default (``auto``: the worker
process where the run has a second core to itself, the threads inside a process pool's worker;
one thread in those pools); ``--jobs 2`` runs two such benchmarks at once in joblib's worker processes,
as ``uss-experiments`` runs its SLAM jobs (``auto`` is then the threads), each printing its own
same-run ratios: the speed under the load of two parallel jobs.

``--prefetch-mode readers`` runs the worker process with ``slam.workers`` (2) reading threads
and with one (``process/1:w``; ``slam.workers=1``, which the ``uss-slam`` process's own
prefetch threads then use too) in turns: the same trajectories, one thread fewer taking turns
under the worker's GIL. ``--prefetch-mode reader-threads`` runs the worker process with 2
reading threads (``process:w``: ``slam.reader_threads=null``, the default before the afternoon
of 2026-12-07) and with ``slam.reader_threads=1`` (``process:1``, today's default: the worker
process's threads alone; the ``uss-slam`` process's prefetch threads stay ``slam.workers``) in
turns.

``--orbslam3 VOCAB`` also runs the real ORB-SLAM3 on the same frames in the same command
(``uss-slam system=orbslam3 system.repeats=--repeats system.realtime=false``: as fast as it
tracks, unfiltered, after the harness's repeats)
and prints its median frames/s (frame reading and tracking, its own local-mapping and
loop-closing threads beside) and the harness's ratio to it.

``--candidate KEY=VALUE`` (repeatable; keys of ``slam.tracker``, ``slam.local_ba_params``,
``slam.loop_closing_params`` or ``slam.orb``, e.g. ``local_ba_params.first_iterations=2``) runs
every repeat twice, in turns, in the one ``--prefetch-mode``: with today's settings and with
these (``MODE+candidate``), and prints the ratios of each pair: frames/s and the CPU ms per frame
of the main thread and of the main process (the figures that survive a busy machine).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from uss_slam.core import png_inflate
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend import process as frontend_process
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.mapping.local_mapping import LocalMappingConfig
from uss_slam.slam_eval.mapping.loop_closing import LoopClosingConfig
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems import harness
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.config import TrackerConfig
from uss_slam.testing.harness_runs import sequence_path
from uss_slam.testing.machine import cpu_model


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0].replace("\n", " "),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--data", type=Path, default=Path("outputs/bench/slam"),
                        help="folder of rendered sequences (rendered there on first use)")  # fmt: skip
    parser.add_argument("--preset", default="walking_xyz", help="uss-synth preset")
    parser.add_argument("--seed", type=int, default=0, help="uss-synth seed of the sequence")
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
    parser.add_argument("--prefetch-mode", choices=(*MODES, *PAIRS), default="both",
                        help="slam.prefetch_mode; both: thread and process in turns in every "
                             "repeat; defaults: before and auto in turns (module docstring)")  # fmt: skip
    parser.add_argument("--jobs", type=int, default=1,
                        help="run this many benchmarks at once in joblib's worker processes "
                             "(as uss-experiments runs SLAM jobs); 1 = in this process")  # fmt: skip
    parser.add_argument(
        "--orbslam3", type=Path, metavar="VOCAB", help="also time ORB-SLAM3 with this vocabulary"
    )
    parser.add_argument("--candidate", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting of the candidate run (module docstring; repeatable)")  # fmt: skip
    args = parser.parse_args()
    if args.candidate:
        if args.prefetch_mode in PAIRS:
            raise SystemExit("--candidate: give one --prefetch-mode (thread, process, auto)")
        candidate_settings(args.candidate)  # a bad key or value stops here
    if args.orbslam3 is not None and not args.orbslam3.is_file():
        raise SystemExit(f"--orbslam3: {args.orbslam3} is not a file (uss-vocab build makes one)")
    if args.jobs < 1:
        raise SystemExit(f"--jobs: expected an integer >= 1, got {args.jobs}")
    size = tuple(int(v) for v in args.size.lower().split("x"))
    path = sequence_path(args.data, args.preset, args.frames, size, args.seed)
    if args.jobs > 1:
        from joblib import Parallel, delayed

        print(f"{args.jobs} jobs at once in joblib's worker processes; load average "
              f"{os.getloadavg()[0]:.2f}", flush=True)  # fmt: skip
        logs = Parallel(n_jobs=args.jobs, backend="loky")(
            delayed(job)(args, path, k) for k in range(args.jobs)
        )
        for k, log in enumerate(logs):
            print(f"----- job {k}\n{log}", end="")
        print(f"load average after: {os.getloadavg()[0]:.2f}")
        return
    benchmark(args, path)


def job(args: argparse.Namespace, path: Path, k: int) -> str:
    """One of ``--jobs`` benchmarks, in a joblib worker: its printed lines."""
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        benchmark(args, path)
    return out.getvalue()


def benchmark(args: argparse.Namespace, path: Path) -> None:
    """Every repeat of the compared modes in turns, their medians and ratios (and ORB-SLAM3's)."""
    size = tuple(int(v) for v in args.size.lower().split("x"))
    seq = TumSequence(path, load_labels=True)
    frames = [seq.load(i) for i in range(len(seq))]
    extractor = OrbExtractor(OrbConfig(), seq.camera)
    print(f"{path}: {len(seq)} frames {size[0]}x{size[1]}, filters {args.filters}, local BA "
          f"{args.local_ba}, loop closing {args.loop_closing}, {os.cpu_count()} CPUs "
          f"({cpu_model()}), load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    print(f"PNG image data inflated by {inflater()}", flush=True)

    modes = PAIRS.get(args.prefetch_mode, [args.prefetch_mode])
    if getattr(args, "candidate", None):
        modes = [args.prefetch_mode, f"{args.prefetch_mode}+candidate"]
        print(f"candidate: {' '.join(args.candidate)}", flush=True)
    print(f"modes {modes}; auto (decided as each run starts) would be "
          f"{frontend_process.resolve_mode('auto')} now", flush=True)  # fmt: skip
    runs: dict[str, list[dict]] = {mode: [] for mode in modes}
    orb_alone = []
    for repeat in range(args.repeats):
        # Both modes in every repeat, in turns (A B, B A, ...): same-run pairs.
        order = modes if repeat % 2 == 0 else modes[::-1]
        for mode in order:
            runs[mode].append(timed_run(seq, args, mode))
            show(repeat, mode, runs[mode][-1], seq)
        start = time.perf_counter()
        for frame in frames:
            extractor(frame.gray, frame.depth)
        orb_alone.append(1000.0 * (time.perf_counter() - start) / len(frames))
        print(f"repeat {repeat}: ORB alone {orb_alone[-1]:.1f} ms/frame", flush=True)
    orb_only = statistics.median(orb_alone)
    fps_of = {}
    for mode in modes:
        done = runs[mode]
        fps_of[mode] = statistics.median(r["fps"] for r in done)
        total = statistics.median(r["timing"]["total"] for r in done)
        each = ", ".join(f"{r['fps']:.1f}" for r in done)
        print(f"[{mode}] median: {fps_of[mode]:.1f} frames/s (runs {each}); pipeline / ORB-only "
              f"{total / orb_only:.2f}")  # fmt: skip
        names = list(done[0]["timing"])
        print(f"[{mode}] median ms per frame: " + ", ".join(
            f"{n} {statistics.median(r['timing'].get(n, 0.0) for r in done):.2f}"
            for n in names))  # fmt: skip
        print(f"[{mode}] median CPU ms per frame: " + ", ".join(
            f"{n} {statistics.median(r['cpu'].get(n, 0.0) for r in done):.2f}"
            for n in done[0]["cpu"]))  # fmt: skip
        for key, text in (
            ("main_thread", "main thread"),
            ("main_process", "main process"),
            ("worker_process", "worker process"),
            ("bound", "CPU-bound rate"),
        ):
            unit = "frames/s on 2 idle cores" if key == "bound" else "CPU ms per frame"
            print(f"[{mode}] median {text}: "
                  f"{statistics.median(r[key] for r in done):.1f} {unit}")  # fmt: skip
    if len(modes) == 2:
        a, b = modes
        pairs = [q["fps"] / p["fps"] for p, q in zip(runs[a], runs[b], strict=True)]
        print(f"{b} / {a} frames/s, per repeat: {', '.join(f'{v:.2f}' for v in pairs)}; "
              f"median {statistics.median(pairs):.2f}")  # fmt: skip
        for key in ("main_thread", "main_process"):
            cpu = [q[key] / p[key] for p, q in zip(runs[a], runs[b], strict=True)]
            print(f"{b} / {a} {key.replace('_', ' ')} CPU ms per frame, per repeat: "
                  f"{', '.join(f'{v:.3f}' for v in cpu)}; median {statistics.median(cpu):.3f}")  # fmt: skip
    if args.orbslam3 is not None:
        orb3 = orbslam3_fps(path, args.orbslam3, args.repeats)
        median3 = statistics.median(orb3)
        print(f"ORB-SLAM3, same frames, no filter: median {median3:.1f} frames/s "
              f"(repeats {', '.join(f'{v:.1f}' for v in orb3)}); harness / ORB-SLAM3: "
              + ", ".join(f"{m} {fps_of[m] / median3:.2f}" for m in modes))  # fmt: skip
    print(f"load average after: {os.getloadavg()[0]:.2f}")


def inflater() -> str:
    """Which inflate the PNG reader uses (core/png_inflate.py): both systems read with it."""
    if png_inflate.isal_zlib is None:
        return "the system zlib (isal is not installed: pip install isal)"
    return "ISA-L (isal)"


MODES = ("thread", "process", "auto", "before")
"""What ``--prefetch-mode`` runs: a ``slam.prefetch_mode``, or ``before`` (the default up to
2026-12-07: the threads, with OpenBLAS's and OpenCV's thread pools as loaded)."""
PAIRS = {
    "both": ["thread", "process"],
    "defaults": ["before", "auto"],
    "readers": ["process:w", "process/1:w"],
    "reader-threads": ["process:w", "process:1"],
}
"""Two modes in turns in every repeat (``MODE/N``: ``MODE`` with ``slam.workers=N``;
``MODE:N``: ``MODE`` with ``slam.reader_threads=N``; ``MODE:w``: with
``slam.reader_threads=null``, the worker process's threads as many as ``slam.workers``)."""

WORKER_MODULES = {"read", "segmentation", "orb"}
"""Modules of the prefetch threads (and of the worker process): the rest is the main thread's."""


def _reader_threads(suffix: str) -> int | None:
    """``slam.reader_threads`` of a mode's ``:N`` suffix (``w``: null, ``slam.workers``)."""
    return None if suffix == "w" else int(suffix)


SECTIONS = {
    "tracker": ("tracker", TrackerConfig),
    "local_ba_params": ("local_ba_params", LocalMappingConfig),
    "loop_closing_params": ("loop_closing_params", LoopClosingConfig),
    "orb": ("orb", OrbConfig),
}
"""``--candidate`` section -> (the :class:`SlamPipeline` keyword, its settings dataclass)."""


def candidate_settings(items: list[str]) -> dict:
    """The :class:`SlamPipeline` keywords of ``--candidate``'s ``SECTION.KEY=VALUE`` items (each
    value read as JSON, else as a string)."""
    values: dict[str, dict] = {}
    for item in items:
        key, eq, text = item.partition("=")
        section, _, name = key.partition(".")
        if not eq or section not in SECTIONS or not name:
            raise SystemExit(f"--candidate: expected SECTION.KEY=VALUE with SECTION one of "
                             f"{', '.join(SECTIONS)}, got {item!r}")  # fmt: skip
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        values.setdefault(section, {})[name] = value
    try:
        return {
            SECTIONS[s][0]: dataclasses.replace(SECTIONS[s][1](), **v) for s, v in values.items()
        }
    except (TypeError, ValueError) as err:
        raise SystemExit(f"--candidate: {err}") from None


def timed_run(seq: TumSequence, args: argparse.Namespace, mode: str) -> dict:
    """One whole-pipeline run: frames/s, per-module wall and CPU ms per frame, the CPU ms per
    frame of the main thread, of this process and of the worker process, and the CPU-bound
    rate on two idle cores (``MODE+candidate``: with ``--candidate``'s settings)."""
    mode, plus, _ = mode.partition("+")
    settings = candidate_settings(args.candidate) if plus else {}
    mode, _, reader_threads = mode.partition(":")
    mode, _, readers = mode.partition("/")
    pipeline = SlamPipeline(
        seq,
        LabelsSegmenter(),
        build_filters(args.filters),
        progress=False,
        local_ba=args.local_ba,
        loop_closing=args.loop_closing,
        prefetch_mode="thread" if mode == "before" else mode,
        **({"workers": int(readers)} if readers else {}),
        **({"reader_threads": _reader_threads(reader_threads)} if reader_threads else {}),
        **settings,
    )
    workers: list[frontend_process.FrontendProcess | None] = []
    start = frontend_process.start

    def recording(*args, **kwargs):  # the worker's own CPU clock (a fork server's child)
        workers.append(start(*args, **kwargs))
        return workers[-1]

    frontend_process.start = recording
    pools = harness.one_thread_pools
    if mode == "before":  # the threads with the libraries' own pools (no worker process here)
        harness.one_thread_pools = contextlib.nullcontext
    own = time.process_time()
    try:
        result = pipeline.run()
    finally:
        frontend_process.start = start
        harness.one_thread_pools = pools
    own = time.process_time() - own
    child = sum(w.worker_cpu for w in workers if w is not None)
    n = max(result.frames, 1)
    main_thread = sum(v for k, v in result.cpu_ms.items() if k not in WORKER_MODULES)
    main_process, worker_process = 1000.0 * own / n, 1000.0 * child / n
    # Per frame the two cores need at least half the CPU time of both processes, and at least
    # the main thread's own (it is sequential).
    bound = 1000.0 / max(main_thread, (main_process + worker_process) / 2)
    return {
        "fps": result.fps,
        "timing": result.timing_ms,
        "cpu": result.cpu_ms,
        "main_thread": main_thread,
        "main_process": main_process,
        "worker_process": worker_process,
        "bound": bound,
        "tracked": result.tracked_fraction,
        "used": pipeline.mode_used,
        "ate": ate(seq.groundtruth, result.trajectory).stats.rmse,
    }


def show(repeat: int, mode: str, run: dict, seq: TumSequence) -> None:
    print(
        f"repeat {repeat} [{mode}{' -> ' + run['used'] if mode.startswith('auto') else ''}]: "
        f"{run['fps']:5.1f} frames/s, pipeline "
        f"{run['timing']['total']:.1f} ms/frame; CPU ms/frame: main thread "
        f"{run['main_thread']:.1f}, main process {run['main_process']:.1f}, worker process "
        f"{run['worker_process']:.1f} -> CPU-bound rate on 2 idle cores {run['bound']:.1f} "
        f"frames/s (tracked {run['tracked']:.2f}, ATE RMSE {run['ate']:.6f} m, load "
        f"{os.getloadavg()[0]:.2f})",
        flush=True,
    )


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

"""Does a rewritten hot module give the same results for less CPU? Two copies of one module
(before and after a change) run on the same inputs in one process, in turns; every output is
compared array by array, and the CPU milliseconds a frame (thread clock) of each round are
printed with their ratio. Reported in BENCHMARKS.md ("SLAM harness speed").

- ``orb``: two copies of ``slam_eval/frontend/orb.py``: ``OrbExtractor`` on about ``--frames``
  grey frames of each sequence, with the default settings and ``n_features=2000, min_fast=3``
  (the features compared), then timed with the defaults;
- ``matching``: two copies of ``slam_eval/matching/descriptor.py``: every ``guided_match`` call
  of one whole harness run on each sequence (thread mode, local BA and loop closing, the
  ``semantic`` filter on the ``labels/`` where the sequence has them) is recorded, then replayed
  through both copies (the matches compared).

    git show REV:slam_eval/frontend/orb.py > /tmp/orb_before.py
    python benchmarks/module_ab.py orb /tmp/orb_before.py slam_eval/frontend/orb.py \\
        --sequence SEQ [SEQ ...] --rounds 6
    python benchmarks/module_ab.py matching /tmp/descriptor_before.py \\
        slam_eval/matching/descriptor.py --sequence SEQ [SEQ ...] [--whole-runs 3]

``--whole-runs N`` (``matching``): then N pairs of whole default runs of each sequence in
turns (``slam.prefetch_mode=process``, as on two idle cores), the harness's guided matching
being the one copy's, then the other's: the trajectories compared, and the CPU ms a frame of
the main thread (its modules' clocks), of the main process and of the frame reader process.

A copy that gives other results stops the script with the first difference (exit code 1).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from uss_slam.testing.machine import cpu_model

FIELDS = {
    "orb": ("xy", "uv", "octave", "angle", "response", "descriptors"),
    "matching": ("query", "keypoint", "distance"),
}
"""The outputs compared, per kind."""


def load_copy(path: Path, name: str) -> ModuleType:
    """The module file ``path`` imported under ``name`` (its relative imports must not be
    needed: both hot modules import the package absolutely)."""
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"{path}: not a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def same(a: Any, b: Any, fields: tuple[str, ...]) -> str | None:
    """The first of ``fields`` where ``a`` and ``b`` differ, else None."""
    return next((f for f in fields if not np.array_equal(getattr(a, f), getattr(b, f))), None)


def in_turns(
    before: Callable[[], None], after: Callable[[], None], frames: int, rounds: int
) -> tuple[list[float], list[float]]:
    """CPU ms a frame of ``before`` and ``after`` (each a whole pass), ``rounds`` each,
    alternating which goes first."""
    times: tuple[list[float], list[float]] = ([], [])
    for r in range(rounds):
        order = ((0, before), (1, after)) if r % 2 == 0 else ((1, after), (0, before))
        for slot, run in order:
            start = time.thread_time()
            run()
            times[slot].append((time.thread_time() - start) / frames * 1e3)
    return times


def compare_orb(before: ModuleType, after: ModuleType, grays: list, camera, rounds: int):
    """Features of both copies compared on every frame (two settings), then timed."""
    for settings in ({}, {"n_features": 2000, "min_fast": 3}):
        old = before.OrbExtractor(before.OrbConfig(**settings), camera)
        new = after.OrbExtractor(after.OrbConfig(**settings), camera)
        for k, gray in enumerate(grays):
            differs = same(old(gray, None), new(gray, None), FIELDS["orb"])
            if differs:
                raise SystemExit(f"frame {k} ({settings or 'defaults'}): {differs} differs")
    old = before.OrbExtractor(before.OrbConfig(), camera)
    new = after.OrbExtractor(after.OrbConfig(), camera)
    return in_turns(
        lambda: [old(g, None) for g in grays], lambda: [new(g, None) for g in grays],
        len(grays), rounds,
    )  # fmt: skip


def compare_matching(before: ModuleType, after: ModuleType, calls: list, frames: int, rounds: int):
    """Every recorded ``guided_match`` call through both copies: the same matches, then timed."""
    for k, (args, kwargs) in enumerate(calls):
        differs = same(
            before.guided_match(*args, **kwargs), after.guided_match(*args, **kwargs),
            FIELDS["matching"],
        )  # fmt: skip
        if differs:
            raise SystemExit(f"call {k}: {differs} differs")
    return in_turns(
        lambda: [before.guided_match(*a, **k) for a, k in calls],
        lambda: [after.guided_match(*a, **k) for a, k in calls],
        frames, rounds,
    )  # fmt: skip


def recorded_calls(path: Path) -> tuple[list, int]:
    """Every ``guided_match`` call of one harness run on ``path``, and its frame count."""
    from uss_slam.slam_eval.filters.build import build_filters
    from uss_slam.slam_eval.matching import projection
    from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
    from uss_slam.slam_eval.sequence import TumSequence
    from uss_slam.slam_eval.systems.harness import SlamPipeline

    labelled = (path / "labels").is_dir()
    sequence = TumSequence(path, load_labels=labelled)
    calls: list = []
    plain = projection.guided_match

    def recording(*args, **kwargs):
        calls.append((args, kwargs))
        return plain(*args, **kwargs)

    projection.guided_match = recording
    try:
        SlamPipeline(
            sequence,
            LabelsSegmenter() if labelled else NoSegmenter(),
            build_filters(["semantic"] if labelled else []),
            progress=False, local_ba=True, loop_closing=True, prefetch_mode="thread",
        ).run()  # fmt: skip
    finally:
        projection.guided_match = plain
    return calls, len(sequence)


def whole_runs(before: ModuleType, after: ModuleType, path: Path, pairs: int) -> None:
    """``pairs`` pairs of whole runs on ``path`` in turns, guided matching from ``before`` /
    ``after``: identical trajectories, CPU ms a frame per pair and their ratios."""
    from uss_slam.slam_eval.matching import projection

    plain = projection.guided_match
    clocks: tuple[list[dict], list[dict]] = ([], [])
    try:
        for r in range(pairs):
            for slot in (0, 1) if r % 2 == 0 else (1, 0):
                projection.guided_match = (before, after)[slot].guided_match
                clocks[slot].append(timed_run(path))
    finally:
        projection.guided_match = plain
    if len({c.pop("trajectory") for c in clocks[0] + clocks[1]}) != 1:
        raise SystemExit(f"{path.name}: the whole runs' trajectories differ")
    for key in clocks[0][0]:
        old, new = [c[key] for c in clocks[0]], [c[key] for c in clocks[1]]
        ratios = [b / a for a, b in zip(old, new, strict=True)]
        print(f"{path.name}, whole runs (the same trajectory): {key} CPU ms/frame before "
              f"{statistics.median(old):.2f}, after {statistics.median(new):.2f}; after / "
              f"before per pair {', '.join(f'{x:.3f}' for x in ratios)} (median "
              f"{statistics.median(ratios):.3f}; load {os.getloadavg()[0]:.1f})")  # fmt: skip


def timed_run(path: Path) -> dict:
    """One whole default run (``semantic`` on the labels where there are some, the back end,
    the frame reader process): its CPU ms a frame and its trajectory's bytes."""
    from uss_slam.slam_eval.filters.build import build_filters
    from uss_slam.slam_eval.frontend import process
    from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
    from uss_slam.slam_eval.sequence import TumSequence
    from uss_slam.slam_eval.systems.harness import SlamPipeline

    labelled = (path / "labels").is_dir()
    workers: list = []
    start = process.start
    process.start = lambda *a, **k: workers.append(start(*a, **k)) or workers[-1]
    own = time.process_time()
    try:
        result = SlamPipeline(
            TumSequence(path, load_labels=labelled),
            LabelsSegmenter() if labelled else NoSegmenter(),
            build_filters(["semantic"] if labelled else []),
            progress=False, local_ba=True, loop_closing=True, prefetch_mode="process",
        ).run()  # fmt: skip
    finally:
        process.start = start
    n = max(result.frames, 1)
    worker = sum(w.worker_cpu for w in workers if w is not None)
    traj = result.trajectory
    return {
        "main thread": sum(
            v for k, v in result.cpu_ms.items() if k not in ("read", "segmentation", "orb")
        ),
        "main process": 1e3 * (time.process_time() - own) / n,
        "worker process": 1e3 * worker / n,
        "trajectory": traj.positions.tobytes() + traj.quaternions.tobytes(),
    }


def report(name: str, what: str, times: tuple[list[float], list[float]]) -> None:
    before, after = times
    ratios = [a / b for a, b in zip(after, before, strict=True)]
    print(f"{name}: {what} identical; CPU ms/frame before {statistics.median(before):.2f}, "
          f"after {statistics.median(after):.2f}; after / before per round "
          f"{', '.join(f'{r:.3f}' for r in ratios)} (median {statistics.median(ratios):.3f})")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("kind", choices=tuple(FIELDS))
    parser.add_argument("before", type=Path, help="the module file before the change")
    parser.add_argument("after", type=Path, help="the module file after the change")
    parser.add_argument("--sequence", type=Path, nargs="+", required=True)
    parser.add_argument("--frames", type=int, default=100, help="orb: frames of each sequence")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--whole-runs", type=int, default=0, metavar="N",
                        help="matching: then N pairs of whole runs in turns (docstring)")  # fmt: skip
    args = parser.parse_args()
    import cv2

    from uss_slam.slam_eval.sequence import TumSequence

    cv2.setNumThreads(1)  # as in the harness's runs (one thread in OpenCV's pool)
    before, after = load_copy(args.before, "before_copy"), load_copy(args.after, "after_copy")
    print(f"{args.kind}: {args.before} -> {args.after}; {os.cpu_count()} CPUs ({cpu_model()}), "
          f"load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    for path in args.sequence:
        if args.kind == "orb":
            sequence = TumSequence(path)
            step = max(1, len(sequence) // args.frames)
            grays = [sequence.load_colour(i)[1] for i in range(0, len(sequence), step)]
            times = compare_orb(before, after, grays, sequence.camera, args.rounds)
            report(path.name, f"features of {len(grays)} frames", times)
        else:
            calls, frames = recorded_calls(path)
            times = compare_matching(before, after, calls, frames, args.rounds)
            report(path.name, f"{len(calls)} calls", times)
            if args.whole_runs > 0:
                whole_runs(before, after, path, args.whole_runs)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

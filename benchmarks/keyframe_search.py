"""What does the brute-force keyframe search cost? Relocalisation and loop closing match a frame's
descriptors to the map points of every keyframe (``slam_eval/matching/keyframe.py``, ORB-SLAM2's
``SearchByBoW`` without its bag of words); ORB-SLAM2 asks its bag-of-words database for a short
list first. Reported in docs/slam-internals.md, "Keyframe search: brute force".

    python benchmarks/keyframe_search.py --data ../shared/data/tum --stride 1

Per TUM stretch in ``--data`` (``--camera``, fr1 by default): one harness run with its defaults
(local BA and loop closing, no filter), every call of the keyframe match timed by its caller
(``reference`` keyframe, ``relocalisation``, ``loop_closing``) in the calling thread's CPU time;
then every keyframe of the final map matched to every other with loop closing's thresholds: CPU ms
per call. A map of K keyframes costs loop closing up to K - 1 calls per new keyframe (about
K²/2 over a run) and relocalisation K calls per lost frame; the last lines extrapolate that
(an estimate, marked so). The machine's load average is printed with the figures.
"""

from __future__ import annotations

import argparse
import os
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.slam_eval.mapping import loop_closing
from uss_slam.slam_eval.matching import keyframe
from uss_slam.slam_eval.segmenters.base import NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.frame_loop import Timer
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking import relocalisation, tracker

CALLERS = {"reference": tracker, "relocalisation": relocalisation, "loop_closing": loop_closing}
"""Caller name -> the module whose ``match_keyframe`` is timed."""


class Timed:
    """Each caller's ``match_keyframe`` counted and timed (CPU s of the calling thread)."""

    def __init__(self) -> None:
        self.calls: Counter[str] = Counter()
        self.cpu: Counter[str] = Counter()

    def wrap(self, name: str) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.thread_time()
            try:
                return keyframe.match_keyframe(*args, **kwargs)
            finally:
                self.cpu[name] += time.thread_time() - start
                self.calls[name] += 1

        return timed

    def __enter__(self) -> Timed:
        for name, module in CALLERS.items():
            module.match_keyframe = self.wrap(name)  # type: ignore[attr-defined]
        return self

    def __exit__(self, *exc: object) -> None:
        for module in CALLERS.values():
            module.match_keyframe = keyframe.match_keyframe  # type: ignore[attr-defined]


def run_stretch(path: Path, camera: str | None, stride: int) -> dict[str, Any]:
    """One harness run over ``path`` with its calls timed, then the all-pairs match cost."""
    seq = TumSequence(path, camera=camera, stride=stride)
    pipeline = SlamPipeline(seq, NoSegmenter(), [], local_ba=True, loop_closing=True,
                            progress=False, parallel=False)  # fmt: skip
    start = time.thread_time()
    with Timed() as timed:
        loop = pipeline._frame_loop(Timer())
        for frame in seq.frames():
            loop.step(pipeline._prepare(frame))
    run_cpu = time.thread_time() - start
    return {"frames": len(loop.log), "run_cpu_s": run_cpu, "calls": dict(timed.calls),
            "cpu_s": dict(timed.cpu), **pair_cost(loop.map)}  # fmt: skip


def pair_cost(slam_map: Any) -> dict[str, Any]:
    """Every good keyframe's static keypoints matched to every other's map points with loop
    closing's thresholds: ``keyframes``, ``pairs`` and CPU ``ms_per_call``."""
    cfg = loop_closing.LoopClosingConfig()
    kfs = [k for k in slam_map.keyframes if not k.bad]
    cpu, pairs = 0.0, 0
    for a in kfs:
        query = np.flatnonzero(~a.dynamic)
        for b in kfs:
            if b is a:
                continue
            start = time.thread_time()
            keyframe.match_keyframe(slam_map, a.features, query, b, cfg.ratio, cfg.max_hamming,
                                    cfg.min_matches)  # fmt: skip
            cpu += time.thread_time() - start
            pairs += 1
    return {"keyframes": len(kfs), "pairs": pairs, "ms_per_call": 1000 * cpu / max(pairs, 1)}


def report(name: str, r: dict[str, Any]) -> list[str]:
    """The lines of one stretch."""
    calls = ", ".join(f"{k} {r['calls'][k]} calls {1000 * r['cpu_s'][k]:.0f} ms"
                      for k in CALLERS if k in r["calls"]) or "none"  # fmt: skip
    share = sum(r["cpu_s"].values()) / r["run_cpu_s"] if r["run_cpu_s"] else 0.0
    lines = [
        f"{name}: {r['frames']} frames, {r['keyframes']} keyframes, main-thread CPU "
        f"{r['run_cpu_s']:.1f} s; keyframe matches: {calls} ({100 * share:.1f}% of it)",
        f"  one match (keyframe to keyframe, {r['pairs']} pairs): {r['ms_per_call']:.2f} ms CPU",
    ]
    for k in (100, 300, 1000):  # loop closing over a run; relocalisation per lost frame
        lines.append(
            f"  estimate, a map of {k} keyframes: loop closing ~{k * (k - 1) / 2 * r['ms_per_call'] / 1000:.0f} s "
            f"CPU over the run, relocalisation ~{k * r['ms_per_call']:.0f} ms per lost frame"
        )  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data/tum"),
                        help="a folder of TUM RGB-D stretches (one sub-folder each)")  # fmt: skip
    parser.add_argument("--camera", default="fr1", help="sequence.camera of the stretches")
    parser.add_argument("--stride", type=int, default=1, help="use every stride-th frame")
    args = parser.parse_args(argv)
    if args.stride < 1:
        parser.error(f"--stride: expected an integer >= 1, got {args.stride}")
    stretches = sorted(p for p in args.data.iterdir() if (p / "rgb.txt").is_file()) \
        if args.data.is_dir() else []  # fmt: skip
    if not stretches:
        parser.error(f"--data={args.data}: expected a folder of TUM RGB-D stretches")
    print(f"load average before: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)")
    for path in stretches:
        print("\n".join(report(path.name, run_stretch(path, args.camera, args.stride))))
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Where and why does the tracker lose a synthetic sequence, and where does its error build up?
Reported in BENCHMARKS.md, "SLAM harness" / "Accuracy targets".

Runs the unfiltered baseline and ``labels`` + ``semantic`` on one sequence and prints, per run,
the stretches of frames not tracked together with what the view holds there (ground-truth
``labels/`` and depth: share of the image on a person, share that is static *and* has depth,
share of the person without depth, i.e. closer than the sensor's minimum range), and the frames
with the largest ATE (SE(3)-aligned, per frame). With ``--plot`` also the ATE of both runs over
time in one PNG. Used in BENCHMARKS.md ("SLAM harness": walking targets over seeds).

    python studies/slam_lost.py /tmp/st12/walking_xyz_300_640x480_seed1 --plot ate.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import RunResult, SlamPipeline

PERSON = CLASS_NAMES.index("person")


def stretches(tracked: np.ndarray) -> list[tuple[int, int]]:
    """``(first, last)`` frame indices of each run of untracked frames."""
    out: list[tuple[int, int]] = []
    start = None
    for i, ok in enumerate(tracked):
        if not ok and start is None:
            start = i
        if ok and start is not None:
            out.append((start, i - 1))
            start = None
    if start is not None:
        out.append((start, len(tracked) - 1))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", type=Path, help="a synthetic sequence folder (with labels/)")
    parser.add_argument("--worst", type=int, default=6, help="frames with the largest ATE to list")
    parser.add_argument("--plot", type=Path, help="write the ATE over time of both runs here")
    args = parser.parse_args()
    seq = TumSequence(args.sequence, load_labels=True)
    person, static_depth, person_no_depth = [], [], []
    for i in range(len(seq)):
        frame = seq.load(i)
        on = frame.labels == PERSON
        person.append(on.mean())
        static_depth.append((~on & (frame.depth > 0)).mean())
        person_no_depth.append((on & (frame.depth <= 0)).mean())
    person_a, static_a, hidden_a = map(np.asarray, (person, static_depth, person_no_depth))
    print(
        f"{args.sequence.name}: {len(seq)} frames; person {person_a.mean():.2f} of the image on "
        f"average (max {person_a.max():.2f}); static with depth min {static_a.min():.2f}, "
        f"below 0.10 on {(static_a < 0.10).sum()} frames"
    )
    curves = {}
    for name, filters in (("baseline", []), ("semantic", ["semantic"])):
        result: RunResult = SlamPipeline(
            seq, LabelsSegmenter(), build_filters(filters), progress=False
        ).run()
        tracked = np.array([e.tracked for e in result.log])
        err = ate(seq.groundtruth, result.trajectory)
        print(
            f"\n{name}: ATE RMSE {1000 * err.stats.rmse:.1f} mm, tracked "
            f"{result.tracked_fraction:.2f}, lost {result.lost_events}x, relocalised "
            f"{result.relocalisations}x, {result.keyframes} keyframes"
        )
        for a, b in stretches(tracked):
            sl = slice(a, b + 1)
            print(
                f"  lost frames {a}-{b}: person {person_a[sl].min():.2f}-{person_a[sl].max():.2f}"
                f", static with depth {static_a[sl].min():.2f}-{static_a[sl].max():.2f}, "
                f"person without depth {hidden_a[sl].min():.2f}-{hidden_a[sl].max():.2f}"
            )
        index = {e.stamp: e.index for e in result.log}
        frames = np.array([index[s] for s in err.stamps])
        worst = np.argsort(-err.errors, kind="stable")[: args.worst]
        listed = ", ".join(
            f"{frames[k]} ({1000 * err.errors[k]:.1f} mm, person {person_a[frames[k]]:.2f})"
            for k in sorted(worst, key=lambda k: frames[k])
        )
        print(f"  largest ATE at frames: {listed}")
        curves[name] = (frames, err.errors, err.stats.rmse)
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(9, 3.5))
        for name, (frames, errors, rmse) in curves.items():
            ax.plot(frames, 1000 * errors, label=f"{name} (RMSE {1000 * rmse:.1f} mm)")
        ax2 = ax.twinx()
        ax2.fill_between(np.arange(len(person_a)), person_a, color="grey", alpha=0.2)
        ax2.set_ylabel("person share of the image")
        ax2.set_ylim(0, 1)
        ax.set_xlabel("frame")
        ax.set_ylabel("ATE [mm]")
        ax.set_title(args.sequence.name)
        ax.legend(loc="upper left")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=80)
        print(f"\nplot: {args.plot}")


if __name__ == "__main__":
    main()

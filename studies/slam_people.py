"""How much do the people of a synthetic sequence get into the unfiltered tracker's pose estimates?
Reported in BENCHMARKS.md, "SLAM harness" / "Accuracy targets" (what it measures; no figure of it is
recorded yet).

Runs the pipeline without filters and, per frame, counts the keypoints on a person (ground-truth
``labels/``) and how many of them are inliers of the final pose (matched to a map point after
PnP-RANSAC and the χ² tests). Also the error over time against ground truth: ATE RMSE and the
frames with the largest one-frame relative pose error.

    python studies/slam_people.py outputs/bench/slam/walking_xyz_300_640x480_seed1
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.slam_eval.scoring.metrics import ate, rpe
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.tracker import Tracker

PERSON = CLASS_NAMES.index("person")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", type=Path, help="a synthetic sequence folder (with labels/)")
    parser.add_argument("--worst", type=int, default=8, help="frames with the largest RPE to list")
    args = parser.parse_args()
    seq = TumSequence(args.sequence, load_labels=True)
    labels = {i: seq.load(i).labels for i in range(len(seq))}
    rows: list[tuple[int, int, int, int]] = []  # frame, keypoints, on a person, person inliers
    inliers: list[int] = []
    finish = Tracker.finish_frame

    def counting(self, index, stamp, result, features, dynamic, keyframe=None):  # noqa: ANN001
        lab = labels[index]
        xy = np.rint(features.xy).astype(int)
        xy = np.clip(xy, 0, [lab.shape[1] - 1, lab.shape[0] - 1])
        person = lab[xy[:, 1], xy[:, 0]] == PERSON
        matched = result.matched if result.matched is not None else np.full(len(person), -1)
        rows.append((index, len(person), int(person.sum()), int((person & (matched >= 0)).sum())))
        inliers.append(int((matched >= 0).sum()))
        return finish(self, index, stamp, result, features, dynamic, keyframe)

    Tracker.finish_frame = counting
    try:
        result = SlamPipeline(seq, LabelsSegmenter(), [], progress=False).run()
    finally:
        Tracker.finish_frame = finish
    r = np.asarray(rows, dtype=float)
    n_in = np.asarray(inliers, dtype=float)
    share = r[:, 3] / np.maximum(n_in, 1)
    print(f"{args.sequence.name}: {len(r)} frames, no filter")
    print(f"keypoints on a person: {r[:, 2].sum() / r[:, 1].sum():.3f} of all keypoints "
          f"({r[:, 2].mean():.1f} per frame)")  # fmt: skip
    print(f"pose inliers on a person: {r[:, 3].sum() / n_in.sum():.3f} of all inliers "
          f"({r[:, 3].mean():.1f} of {n_in.mean():.1f} per frame); frames where people hold "
          f"> 10% of the inliers: {int((share > 0.1).sum())}, largest share {share.max():.3f}")  # fmt: skip
    stats = ate(seq.groundtruth, result.trajectory)
    rel = rpe(seq.groundtruth, result.trajectory, delta=1, unit="frames")
    worst = np.argsort(rel.trans_errors)[-args.worst :][::-1]
    print(f"ATE RMSE {1000 * stats.stats.rmse:.2f} mm; largest one-frame RPE (pair index: mm): "
          + ", ".join(f"{i}: {1000 * rel.trans_errors[i]:.1f}" for i in worst))  # fmt: skip


if __name__ == "__main__":
    main()

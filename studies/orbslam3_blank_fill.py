"""Which grey should dynamic pixels be blanked with for ORB-SLAM3, judged by the ORB keypoints at
the blanked region? Reported in BENCHMARKS.md, "ORB-SLAM3 next to the harness".

A flat region has no FAST corners inside; its border against the rest of the image can. For
every ``--stride``-th frame with people of a synthetic sequence, the person mask is dilated as
the harness's semantic filter does (5 px) and filled with black (0), mid-grey (128) or the mean
grey of the unmasked pixels; ORB (cv2, ORB-SLAM's 1000 features / 1.2 / 8 levels / FAST 20,
ranked by FAST response) runs on each, and the keypoints within 10 px of the mask (inside it or on its border) are
counted with their mean response, next to the unblanked frame.

    python studies/orbslam3_blank_fill.py --sequence outputs/bench/orbslam3/walking_xyz_300_seed7
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.orbslam3.masking import dynamic_mask
from uss_slam.slam_eval.systems.orbslam3.vocabulary import ORB_SETTINGS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequence", type=Path, required=True)
    parser.add_argument("--stride", type=int, default=10)
    args = parser.parse_args()
    seq = TumSequence(args.sequence, load_labels=True, stride=args.stride)
    semantic = SemanticFilter(["person"], 5)
    orb = cv2.ORB_create(**ORB_SETTINGS)
    orb.setScoreType(cv2.ORB_FAST_SCORE)  # ORB-SLAM ranks corners by FAST response
    near = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (21, 21))
    fills: dict[str, list[float]] = {"unblanked": [], "0 (black)": [], "128 (grey)": [], "mean": []}
    counts = dict.fromkeys(fills, 0)
    frames = 0
    for frame in seq.frames():
        mask = dynamic_mask(frame, frame.labels, [semantic])
        if not mask.any():
            continue
        frames += 1
        band = cv2.dilate(mask.astype(np.uint8), near) > 0
        for name in fills:
            gray = frame.gray.copy()
            if name != "unblanked":
                gray[mask] = (
                    int(frame.gray[~mask].mean()) if name == "mean" else int(name.split()[0])
                )
            keypoints = orb.detect(gray, None)
            for kp in keypoints:
                x = min(max(round(kp.pt[0]), 0), gray.shape[1] - 1)
                y = min(max(round(kp.pt[1]), 0), gray.shape[0] - 1)
                if band[y, x]:
                    counts[name] += 1
                    fills[name].append(kp.response)
    print(f"{seq.path.name}: {frames} frames with people (every {args.stride}th)")
    print("| fill | keypoints within 10 px of the mask | per frame | mean response |")
    print("|---|---|---|---|")
    for name, responses in fills.items():
        mean = float(np.mean(responses)) if responses else 0.0
        print(f"| {name} | {counts[name]} | {counts[name] / max(frames, 1):.1f} | {mean:.2e} |")


if __name__ == "__main__":
    main()

"""What does a trained segmenter's blanking leave ORB-SLAM3 to track: how many ORB keypoints on the
walkers, for each fill? Reported in docs/results/shifts.md, "ORB-SLAM3's blanked input and masks
that cover part of a walker (2026-12-05)".

ORB-SLAM3 takes no masks, so ``uss-slam system=orbslam3`` blanks the segmenter's dilated person
mask in its input (flat grey, depth 0). A mask that covers only part of a walker leaves the rest
of him in the image, and the edge of the grey region then runs across him and moves with him:
FAST fires on that edge. This counts, for every ``--stride``-th frame with people of a labelled
sequence and for every ``--model`` (an ONNX export; ``labels`` for the ground-truth masks), the
ORB keypoints (cv2, ORB-SLAM's 1000 features / 1.2 / 8 levels / FAST 20, ranked by FAST
response) that land on the walkers (ground-truth person pixels) with a depth, i.e. the ones
ORB-SLAM3 can turn into map points, in the image as it is and as each fill leaves it (the
colour image filled as ``uss-slam`` fills it, then converted to grey as ORB-SLAM3 does):

- ``grey``: the mask set to grey 128 (``system.blank_fill=grey``, the default);
- ``inpaint``: the mask filled from its surroundings (``system.blank_fill=inpaint``:
  ``cv2.inpaint``, Telea, radius 5), a smooth continuation with a weaker edge;
- ``smooth``: the mask filled with the mean of the unmasked pixels around it, Gaussian-weighted
  (sigma 15 px: a normalised convolution; two blurs, much cheaper than inpainting).

Printed per model and fill: the mean over frames of the walker keypoints with depth, of all
keypoints with depth, and the walkers' share of them (the dynamic share), with the pixel recall
of the mask on the walkers. ::

    python studies/orbslam3_partial_masks.py --sequence OUT/data/train/target_val/walking_rpy \\
        --model labels --model RUNS/exports/source_only_s0.onnx [--stride 10] [--json F]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.orbslam3.masking import (
    blank_dynamic,
    dynamic_mask,
    fill_dynamic,
)
from uss_slam.slam_eval.systems.orbslam3.vocabulary import ORB_SETTINGS

FILLS = ("unblanked", "grey", "inpaint", "smooth")
PERSON = CLASS_NAMES.index("person")


def smooth_fill(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``rgb`` with the ``mask`` pixels set to the Gaussian-weighted mean (sigma 15 px) of the
    unmasked pixels around them (a normalised convolution)."""
    keep = (~mask).astype(np.float32)
    num = cv2.GaussianBlur(rgb.astype(np.float32) * keep[..., None], (0, 0), 15)
    den = cv2.GaussianBlur(keep, (0, 0), 15)[..., None]
    out = rgb.copy()
    out[mask] = np.clip(num / np.maximum(den, 1e-6), 0, 255).astype(np.uint8)[mask]
    return out


def filled(frame: Any, mask: np.ndarray, how: str) -> tuple[np.ndarray, np.ndarray]:
    """(grey image, depth) of ``frame`` as ORB-SLAM3 gets it with the ``mask`` filled ``how``
    (one of :data:`FILLS`): the colour image filled as ``uss-slam`` fills it
    (:func:`blank_dynamic`, :func:`fill_dynamic`), then converted to grey as ORB-SLAM3 does."""
    if how == "unblanked":
        return frame.gray, frame.depth
    if how not in FILLS:
        raise ValueError(f"fill: one of {', '.join(FILLS)}, got {how!r}")
    other = {"grey": None, "inpaint": lambda: fill_dynamic(frame.rgb, mask, "inpaint"),
             "smooth": lambda: smooth_fill(frame.rgb, mask)}[how]  # fmt: skip
    rgb, depth = blank_dynamic(
        frame.rgb, frame.depth, mask, 128, None if other is None else other()
    )
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), depth


def count(gray: np.ndarray, depth: np.ndarray, walker: np.ndarray, orb: Any) -> tuple[int, int]:
    """(keypoints on ``walker`` pixels, all keypoints), both only where ``depth`` > 0."""
    on_walker = total = 0
    h, w = gray.shape
    for kp in orb.detect(gray, None):
        x = min(max(round(kp.pt[0]), 0), w - 1)
        y = min(max(round(kp.pt[1]), 0), h - 1)
        if depth[y, x] > 0:
            total += 1
            on_walker += int(walker[y, x])
    return on_walker, total


def measure(seq: TumSequence, masks: dict[int, np.ndarray], orb: Any) -> dict[str, Any]:
    """Per fill: mean walker / all keypoints with depth per frame and the mean dynamic share;
    the masks' pixel recall on the walkers (frames with people only)."""
    sums = {f: [0.0, 0.0, 0.0] for f in FILLS}
    frames = hit = people = 0
    for frame in seq.frames():
        walker = frame.labels == PERSON
        if not walker.any():
            continue
        mask = masks[frame.index]
        frames += 1
        hit += int((walker & mask).sum())
        people += int(walker.sum())
        for how in FILLS:
            gray, depth = filled(frame, mask, how)
            dyn, total = count(gray, depth, walker, orb)
            sums[how][0] += dyn
            sums[how][1] += total
            sums[how][2] += dyn / max(total, 1)
    if not frames:
        raise SystemExit(f"{seq.path}: no frame with people among the ones read")
    return {
        "frames": frames,
        "recall": hit / people,
        **{how: {"walker": s[0] / frames, "all": s[1] / frames, "share": s[2] / frames}
           for how, s in sums.items()},
    }  # fmt: skip


def model_masks(seq: TumSequence, model: str, semantic: SemanticFilter) -> dict[int, np.ndarray]:
    """Every read frame's dilated person mask from ``model`` (``labels``: the ground truth)."""
    if model == "labels":
        return {f.index: dynamic_mask(f, f.labels, [semantic]) for f in seq.frames()}
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    segmenter = OnnxSegmenter(model, threads=1)
    names = segmenter.metadata.class_names
    if "person" not in names:
        raise SystemExit(f"{model}: the model has no class person ({', '.join(names)})")
    return {f.index: dynamic_mask(f, segmenter.segment(f), [semantic]) for f in seq.frames()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequence", type=Path, required=True, help="a labelled sequence")
    parser.add_argument("--model", action="append", required=True,
                        help="an ONNX export, or 'labels' (repeat the option)")  # fmt: skip
    parser.add_argument("--stride", type=int, default=10)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    if args.stride < 1:
        parser.error(f"--stride: a frame stride >= 1, got {args.stride}")
    for model in args.model:
        if model != "labels" and not Path(model).is_file():
            parser.error(f"--model {model}: no such file (an ONNX export, or 'labels')")
    seq = TumSequence(args.sequence, load_labels=True, stride=args.stride)
    semantic = SemanticFilter(["person"], 5)
    orb = cv2.ORB_create(**ORB_SETTINGS)
    orb.setScoreType(cv2.ORB_FAST_SCORE)  # ORB-SLAM ranks corners by FAST response
    results = {}
    print(f"{seq.path}: every {args.stride}th frame; keypoints with depth per frame "
          "(on the walkers / all, the walkers' share)")  # fmt: skip
    print("| model | mask recall on walkers | " + " | ".join(FILLS) + " |")
    print("|---" * (len(FILLS) + 2) + "|")
    for model in args.model:
        print(f"segmenting with {model} ...", file=sys.stderr, flush=True)
        r = measure(seq, model_masks(seq, model, semantic), orb)
        results[model] = r
        cells = [f"{r[f]['walker']:.0f} / {r[f]['all']:.0f}, {r[f]['share']:.3f}" for f in FILLS]
        print(f"| {Path(model).stem} | {r['recall']:.2f} | " + " | ".join(cells) + " |", flush=True)
    if args.json:
        args.json.write_text(json.dumps({"sequence": str(seq.path), "stride": args.stride,
                                         "results": results}, indent=1))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

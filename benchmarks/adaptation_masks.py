"""Where a segmenter's person masks help or hurt the SLAM front end: per frame, the ORB keypoints
the semantic filter would drop on people (wanted) and on static structure (false alarms), the
people's keypoints it keeps (misses), and each walker's pixel recall by size and distance.

For an exported model (``.onnx``, run through :class:`OnnxSegmenter`, argmax or each
``--threshold`` on the person probability) on labelled TUM folders (``labels/``)::

    python benchmarks/adaptation_masks.py exports/adapted.onnx --sequence SEQ [--sequence SEQ2]
        [--stride 5] [--threshold 0.5 --threshold 0.3 ...] [--dilation 5] [--json out.json]

Keypoints: the harness's :class:`OrbExtractor` (1000 ORB features, ORB-SLAM2 TUM settings) on
each frame. A keypoint is a *person* keypoint when the true person mask, dilated by
``--dilation`` px (the semantic filter's default, 5 px), covers it; the filter drops the
keypoints inside the predicted person mask dilated the same way. Reported per setting:

- pixel metrics of the undilated person mask (``core.seg_metrics``: FPR, FNR, recall,
  precision, PWC pooled over frames; frame-level TP/FN at IoU 0.5);
- ``kp_person_kept``: share of person keypoints the filter keeps (misses; 0 = all removed);
- ``kp_static_dropped``: share of static keypoints it drops (false alarms);
- ``dyn_share``: share of person keypoints among the kept ones (no filter: the raw share);
- walker recall (true-mask pixels found) by the walker's share of the frame and median depth,
  walkers = connected components of the true person mask with at least 0.2% of the frame.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import BinaryCounts, mask_counts, mask_metrics
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter
from uss_slam.slam_eval.sequence import TumSequence

PERSON = CLASS_NAMES.index("person")
SIZE_BINS = (0.0, 0.02, 0.05, 0.10, 0.20, 1.01)
"""Walker area as a share of the frame."""
DEPTH_BINS = (0.0, 1.0, 1.5, 2.0, 3.0, 99.0)
"""Walker median depth, metres."""


def _bin(value: float, edges: tuple[float, ...]) -> str:
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        if lo <= value < hi:
            return f"{lo:g}-{hi:g}"
    return f">{edges[-1]:g}"


class Tally:
    """Counts of one setting (argmax or a threshold) over all frames."""

    def __init__(self) -> None:
        self.pixels: list[BinaryCounts] = []
        self.kp = defaultdict(int)
        self.walkers: dict[str, dict[str, list[int]]] = {"size": {}, "depth": {}}
        self.frames: list[dict[str, float]] = []

    def add(self, truth, pred_person, kp_xy, depth, kernel, frame_name) -> None:
        truth_person = truth == PERSON
        self.pixels.append(mask_counts(truth, np.where(pred_person, PERSON, 0), [PERSON]))
        drop = cv2.dilate(pred_person.astype(np.uint8), kernel) > 0
        on_person = cv2.dilate(truth_person.astype(np.uint8), kernel) > 0
        xi = np.clip(np.round(kp_xy[:, 0]).astype(int), 0, truth.shape[1] - 1)
        yi = np.clip(np.round(kp_xy[:, 1]).astype(int), 0, truth.shape[0] - 1)
        person_kp = on_person[yi, xi]
        dropped = drop[yi, xi]
        counts = {
            "person": int(person_kp.sum()),
            "static": int((~person_kp).sum()),
            "person_kept": int((person_kp & ~dropped).sum()),
            "static_dropped": int((~person_kp & dropped).sum()),
        }
        for k, v in counts.items():
            self.kp[k] += v
        self.frames.append({"frame": frame_name, **counts})
        n, comp, stats, _ = cv2.connectedComponentsWithStats(truth_person.astype(np.uint8), 8)
        area_min = 0.002 * truth.size
        for c in range(1, n):
            area = int(stats[c, cv2.CC_STAT_AREA])
            if area < area_min:
                continue
            inside = comp == c
            found = int(np.count_nonzero(inside & pred_person))
            z = depth[inside]
            z = z[z > 0]
            zmed = float(np.median(z)) if z.size else 0.0
            for kind, key in (("size", _bin(area / truth.size, SIZE_BINS)),
                              ("depth", _bin(zmed, DEPTH_BINS))):  # fmt: skip
                cell = self.walkers[kind].setdefault(key, [0, 0, 0])
                cell[0] += found
                cell[1] += area
                cell[2] += 1

    def summary(self) -> dict:
        m = mask_metrics(self.pixels)
        kp = self.kp
        kept = kp["person_kept"] + kp["static"] - kp["static_dropped"]
        return {
            "pixels": {
                k: m["pixels_pooled"][k] for k in ("FPR", "FNR", "recall", "precision", "PWC")
            },
            "frames": {k: m["frames"]["counts"][k] for k in ("TP", "FP", "TN", "FN")},
            "person_iou": self._iou(),
            "kp_person": kp["person"],
            "kp_static": kp["static"],
            "kp_person_kept": kp["person_kept"] / max(kp["person"], 1),
            "kp_static_dropped": kp["static_dropped"] / max(kp["static"], 1),
            "dyn_share": kp["person_kept"] / max(kept, 1),
            "walker_recall": {
                kind: {
                    k: {"recall": v[0] / max(v[1], 1), "walkers": v[2]}
                    for k, v in sorted(cells.items())
                }  # fmt: skip
                for kind, cells in self.walkers.items()
            },
        }

    def _iou(self) -> float:
        total = BinaryCounts()
        for c in self.pixels:
            total = total + c
        return total.iou


def analyse(model: Path, sequences: list[Path], stride: int, thresholds: list[float | None],
            dilation: int) -> dict:  # fmt: skip
    segmenters = {("argmax" if t is None else f"p>={t:g}"): OnnxSegmenter(model, threshold=t)
                  for t in thresholds}  # fmt: skip
    size = 2 * dilation + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    out: dict = {"model": str(model), "stride": stride, "dilation": dilation, "sequences": {}}
    for seq_path in sequences:
        seq = TumSequence(seq_path, load_labels=True, stride=stride)
        label = f"{seq_path.parent.name}/{seq_path.name}"
        extractor = OrbExtractor(OrbConfig(), seq.camera)
        tallies = {name: Tally() for name in segmenters}
        baseline = Tally()
        for k in range(len(seq)):
            frame = seq.load(k)
            feats = extractor(frame.gray, frame.depth)
            name = f"{label}/{k * stride}"
            empty = np.zeros(frame.labels.shape, bool)
            baseline.add(frame.labels, empty, feats.xy, frame.depth, kernel, name)
            for key, seg in segmenters.items():
                pred = seg.infer(frame.rgb) == PERSON
                tallies[key].add(frame.labels, pred, feats.xy, frame.depth, kernel, name)
        out["sequences"][label] = {
            "frames": len(seq),
            "no_filter": {
                "kp_person": baseline.kp["person"],
                "kp_static": baseline.kp["static"],
                "dyn_share": baseline.summary()["dyn_share"],
            },  # fmt: skip
            **{key: t.summary() for key, t in tallies.items()},
            "per_frame": {key: t.frames for key, t in tallies.items()},
        }
    return out


def table(result: dict) -> str:
    lines = []
    for name, seq in result["sequences"].items():
        lines.append(f"\n{name} ({seq['frames']} frames; no filter: person keypoints "
                     f"{seq['no_filter']['dyn_share']:.1%} of {seq['no_filter']['kp_person'] + seq['no_filter']['kp_static']})")  # fmt: skip
        lines.append("| setting | person IoU | recall | precision | FPR | frames TP/FN/FP | "
                     "person kp kept | static kp dropped | person share of kept kp |")  # fmt: skip
        lines.append("|---|---|---|---|---|---|---|---|---|")
        for key, s in seq.items():
            if key in ("frames", "no_filter", "per_frame"):
                continue
            p, f = s["pixels"], s["frames"]
            lines.append(
                f"| {key} | {s['person_iou']:.3f} | {p['recall']:.3f} | {p['precision']:.3f} | "
                f"{p['FPR']:.4f} | {f['TP']}/{f['FN']}/{f['FP']} | {s['kp_person_kept']:.1%} | "
                f"{s['kp_static_dropped']:.1%} | {s['dyn_share']:.1%} |"
            )
        first = next(k for k in seq if k not in ("frames", "no_filter", "per_frame"))
        for kind in ("size", "depth"):
            cells = seq[first]["walker_recall"][kind]
            desc = ", ".join(f"{k}: {v['recall']:.2f} (n={v['walkers']})" for k, v in cells.items())
            lines.append(f"walker recall by {kind} ({first}): {desc}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("--sequence", type=Path, action="append", required=True)
    parser.add_argument("--stride", type=int, default=5)
    parser.add_argument("--threshold", type=float, action="append", default=[],
                        help="person-probability thresholds besides argmax (repeatable)")  # fmt: skip
    parser.add_argument("--dilation", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    result = analyse(args.model, args.sequence, args.stride, [None, *args.threshold],
                     args.dilation)  # fmt: skip
    print(table(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

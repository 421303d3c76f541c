"""Where do a segmenter's person masks help or hurt the SLAM front end? Per frame, the ORB keypoints
the semantic filter would drop on people (wanted) and on static structure (false alarms), the
people's keypoints it keeps (misses), and each walker's pixel recall by size and distance. Reported
in docs/results/README.md, "2026-12-04 — why AdaptSegNet's masks help with a lower mIoU", and
docs/results/adaptation.md, "1. Evidence: the masks miss the walkers, and the ATE differences were
noise".

For an exported model (``.onnx``, run through :class:`OnnxSegmenter`, argmax or each
``--threshold`` on the person probability) on labelled TUM folders (``labels/``)::

    python studies/adaptation_masks.py exports/adapted.onnx --sequence SEQ [--sequence SEQ2]
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

For every model of a ``uss-experiments`` output folder, joined with its SLAM runs::

    python studies/adaptation_masks.py --experiment OUT [--sequences walking_xyz,walking_rpy]
        [--models source_only_s0,...] [--stride 5] [--json out.json]

scores each export (``OUT/exports/<model>/<model>.onnx``) on the labelled evaluation sequences
(``OUT/data/eval/<sequence>``; each model's result is kept in ``OUT/masks/<model>.json`` and
reused), and puts beside the mask figures each model's SLAM result from ``OUT/runs.csv``: on a
sequence with ground-truth-mask runs, the downstream ratio (ATE_none − ATE_model) / (ATE_none −
ATE_oracle); on ``static_xyz`` (nothing moves) ATE_model / ATE_none. Then, over the trained
models (not the oracle), the Spearman rank correlation of each SLAM ratio with each mask figure:
which property of a mask the SLAM gain follows (person IoU, pixel recall, person keypoints
kept, static keypoints dropped, ...).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import BinaryCounts, mask_counts, mask_metrics
from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.testing.downstream import SLAM_COLUMNS, STATIC, slam_ratios

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


MASK_FIGURES = {
    "person_iou": "person IoU",
    "recall": "pixel recall",
    "precision": "pixel precision",
    "kp_person_kept": "person kp kept",
    "kp_static_dropped": "static kp dropped",
    "dyn_share": "person share of kept kp",
}
"""The mask figures of :meth:`Tally.summary` the experiment mode correlates (key -> label)."""


def _flat(setting: dict) -> dict[str, float]:
    return {"person_iou": setting["person_iou"], "recall": setting["pixels"]["recall"],
            "precision": setting["pixels"]["precision"],
            **{k: setting[k] for k in ("kp_person_kept", "kp_static_dropped", "dyn_share")}}  # fmt: skip


def spearman(xs: list[float], ys: list[float]) -> tuple[float, float] | None:
    """Spearman's rank correlation (average ranks for ties) and its two-sided p-value; None for
    fewer than 3 pairs or a constant side."""
    from scipy.stats import spearmanr

    if len(xs) < 3 or len(set(xs)) < 2 or len(set(ys)) < 2:
        return None
    result = spearmanr(xs, ys)
    rho, p = float(result.statistic), float(result.pvalue)
    return None if math.isnan(rho) else (rho, p)


def join(masks: dict[str, dict], runs: list[dict[str, Any]], sequences: list[str]) -> dict:
    """Per sequence: each model's mask figures and SLAM ratios, and over the trained models
    (every model but ``oracle_*``) the rank correlation of each ratio with each figure."""
    out: dict[str, Any] = {}
    for seq in sequences:
        rows = []
        for model, result in masks.items():
            cell = result["sequences"].get(seq)
            if cell is None:
                continue
            rows.append({"model": model, **_flat(cell["argmax"]), **slam_ratios(runs, seq, model)})
        trained = [r for r in rows if not r["model"].startswith("oracle")]
        corr: dict[str, dict[str, Any]] = {}
        for system, variant in SLAM_COLUMNS:
            key = f"{system}:{variant}"
            have = [r for r in trained if r[key] is not None]
            if have:
                pairs = {f: spearman([r[f] for r in have], [r[key] for r in have])
                         for f in MASK_FIGURES}  # fmt: skip
                corr[key] = {"models": len(have),
                             "rho": {f: None if v is None else v[0] for f, v in pairs.items()},
                             "p": {f: None if v is None else v[1] for f, v in pairs.items()}}  # fmt: skip
        out[seq] = {"models": rows, "spearman": corr}
    return out


def joined_table(joined: dict) -> str:
    def num(v: float | None, pct: bool = False) -> str:
        return "—" if v is None else (f"{v:.1%}" if pct else f"{v:.3f}")

    lines = []
    heads = [*MASK_FIGURES.values(), *(f"{s} {v}" for s, v in SLAM_COLUMNS)]
    for seq, part in joined.items():
        what = "ATE / ATE_none" if seq == STATIC else "downstream ratio"
        lines += [f"\n## {seq} (SLAM columns: {what})", "",
                  "| model | " + " | ".join(heads) + " |", "|---" * (len(heads) + 1) + "|"]  # fmt: skip
        for r in part["models"]:
            cells = [num(r[f], f.startswith("kp_") or f == "dyn_share") for f in MASK_FIGURES]
            cells += [num(r[f"{s}:{v}"]) for s, v in SLAM_COLUMNS]
            lines.append(f"| {r['model']} | " + " | ".join(cells) + " |")
        for key, corr in part["spearman"].items():
            desc = ", ".join(
                f"{MASK_FIGURES[f]} "
                + ("—" if rho is None else f"{rho:+.2f} (p {corr['p'][f]:.2f})")
                for f, rho in corr["rho"].items()
            )
            lines.append(f"\nSpearman over {corr['models']} trained models, {key}: {desc}")
    return "\n".join(lines)


def experiment(out: Path, sequences: list[str] | None, models: list[str] | None,
               stride: int, dilation: int) -> dict:  # fmt: skip
    """The experiment mode (module docstring): score, cache, join."""
    runs_csv = out / "runs.csv"
    if not runs_csv.is_file():
        raise SystemExit(f"{runs_csv}: no runs.csv (expected a uss-experiments output folder "
                         "whose tables stage has run)")  # fmt: skip
    with runs_csv.open(newline="") as f:
        runs = list(csv.DictReader(f))
    found = sorted(p.name for p in (out / "exports").glob("*") if (p / f"{p.name}.onnx").is_file())
    for m in models or []:
        if m not in found:
            raise SystemExit(f"--models: {m} has no export in {out / 'exports'}; found: "
                             f"{', '.join(found) or 'none'}")  # fmt: skip
    eval_dir = out / "data" / "eval"
    labelled = sorted(p.name for p in eval_dir.glob("*") if (p / "labels").is_dir()
                      and (p / "groundtruth.txt").is_file())  # fmt: skip
    for seq in sequences or []:
        if seq not in labelled:
            raise SystemExit(f"--sequences: {seq} is not a labelled evaluation sequence in "
                             f"{eval_dir}; found: {', '.join(labelled) or 'none'}")  # fmt: skip
    sequences = sequences or labelled
    cache = out / "masks"
    cache.mkdir(exist_ok=True)
    masks: dict[str, dict] = {}
    for m in models or found:
        path = cache / f"{m}.json"
        want = {"stride": stride, "dilation": dilation}
        result = json.loads(path.read_text()) if path.is_file() else None
        if result is None or any(result.get(k) != v for k, v in want.items()) or any(
            f"eval/{s}" not in result["sequences"] for s in sequences
        ):  # fmt: skip
            print(f"scoring {m} on {', '.join(sequences)} ...", file=sys.stderr, flush=True)
            result = analyse(out / "exports" / m / f"{m}.onnx", [eval_dir / s for s in sequences],
                             stride, [None], dilation)  # fmt: skip
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(json.dumps(result))
            tmp.replace(path)
        result = {**result, "sequences": {k.removeprefix("eval/"): v
                                          for k, v in result["sequences"].items()}}  # fmt: skip
        masks[m] = result
    return join(masks, runs, sequences)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", type=Path, nargs="?")
    parser.add_argument("--sequence", type=Path, action="append", default=[])
    parser.add_argument("--experiment", type=Path, default=None,
                        help="a uss-experiments output folder: score its every export and join "
                             "the SLAM runs of its runs.csv")  # fmt: skip
    parser.add_argument("--sequences", default=None,
                        help="with --experiment: comma-separated evaluation sequences "
                             "(default: every labelled one)")  # fmt: skip
    parser.add_argument(
        "--models",
        default=None,
        help="with --experiment: comma-separated models (default: every export)",
    )
    parser.add_argument("--stride", type=int, default=5)
    parser.add_argument("--threshold", type=float, action="append", default=[],
                        help="person-probability thresholds besides argmax (repeatable)")  # fmt: skip
    parser.add_argument("--dilation", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.experiment is not None:
        if args.model is not None or args.sequence:
            parser.error("--experiment takes its models and sequences from the folder: give "
                         "no MODEL or --sequence (use --models / --sequences)")  # fmt: skip
        split = lambda v: None if v is None else [x for x in v.split(",") if x]  # noqa: E731
        joined = experiment(args.experiment, split(args.sequences), split(args.models),
                            args.stride, args.dilation)  # fmt: skip
        print(joined_table(joined))
        if args.json:
            args.json.write_text(json.dumps(joined, indent=1))
        return 0
    if args.model is None or not args.sequence:
        parser.error("give MODEL and --sequence (or --experiment OUT)")
    result = analyse(args.model, args.sequence, args.stride, [None, *args.threshold],
                     args.dilation)  # fmt: skip
    print(table(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

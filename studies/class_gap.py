"""Where does the gap to the target oracle lie, per class, and does a class-prior (label) shift
explain it? An evidence probe on a finished ``uss-experiments`` output folder. Reported in
docs/results/README.md, "2026-12-05 — where the gap to the oracle lies (no new training)".

For each exported model and seed (``OUT/exports/<model>_s<seed>/<model>_s<seed>.onnx``):

- per-class IoU on the evaluation sequences (every ``--stride``-th frame of
  ``OUT/data/eval/<sequence>``), and each class's share of the gap between source-only and the
  target oracle (``(IoU_oracle − IoU_source_only) / C`` over the mIoU gap);
- the predicted class fractions against the true ones;
- the same models with their softmax re-weighted for a class-prior shift,
  ``p_t(c|x) ∝ p_s(c|x) · π_t(c) / π_s(c)`` (π_s = the source labels' pixel frequencies of
  ``OUT/data/train/voc``):

  * ``EM``: π_t estimated without labels by EM on the unlabelled target training frames
    (Saerens, Latinne & Decaestecker, Neural Computation 2002; every 10th frame of
    ``OUT/data/train/target_train/*``, every 4th pixel);
  * ``true prior †``: π_t = the target training frames' label frequencies. It **uses target
    labels**: the best a prior correction could do, not a method.

::

    python studies/class_gap.py --experiment OUT [--models source_only,adabn,...]
        [--seeds 0,1,2] [--sequences walking_xyz,walking_rpy] [--stride 10] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import onnxruntime as ort
from PIL import Image

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX, voc_lut
from uss_slam.core.onnx_contract import INPUT_NAME, OUTPUT_LOGITS

C = len(CLASS_NAMES)


def frames(folder: Path, stride: int, labels: bool = True) -> Iterator[tuple[np.ndarray, Any]]:
    """``(rgb, labels)`` of every ``stride``-th frame of a labelled frame folder."""
    paths = sorted((folder / "rgb").glob("*.png"))[::stride]
    if not paths:
        raise SystemExit(f"{folder}/rgb: no PNG frames")
    for p in paths:
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            raise SystemExit(f"{p}: cannot read the image")
        lab = None
        if labels:
            lab = cv2.imread(str(folder / "labels" / p.name), cv2.IMREAD_UNCHANGED)
            if lab is None:
                raise SystemExit(f"{folder / 'labels' / p.name}: missing (expected class ids)")
        yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), lab


def source_prior(out: Path) -> np.ndarray:
    """Pixel frequency of each project class in the source labels (VOC palette PNGs)."""
    files = sorted((out / "data" / "train" / "voc").glob("VOCdevkit/*/SegmentationClass/*.png"))
    if not files:
        raise SystemExit(f"{out}/data/train/voc: no VOC SegmentationClass PNGs")
    lut, count = voc_lut(), np.zeros(C)
    for f in files:
        ids = lut[np.asarray(Image.open(f))]
        count += np.bincount(ids[ids != IGNORE_INDEX].ravel(), minlength=C)[:C]
    return count / count.sum()


def probabilities(session: ort.InferenceSession, rgb: np.ndarray) -> np.ndarray:
    """``(C, H, W)`` softmax of the model's logits at the image size."""
    (logits,) = session.run([OUTPUT_LOGITS], {INPUT_NAME: np.ascontiguousarray(rgb)[None]})
    logits = logits[0].astype(np.float32)
    if logits.shape[1:] != rgb.shape[:2]:
        size = (rgb.shape[1], rgb.shape[0])
        logits = np.stack([cv2.resize(c, size, interpolation=cv2.INTER_LINEAR) for c in logits])
    e = np.exp(logits - logits.max(axis=0))
    return e / e.sum(axis=0)


def em_prior(p: np.ndarray, prior_s: np.ndarray, iterations: int = 200) -> np.ndarray:
    """Saerens et al.'s EM: the target prior under which the re-weighted posteriors ``p``
    (C, N) average to it."""
    prior = prior_s.copy()
    for _ in range(iterations):
        q = p * (prior / prior_s)[:, None]
        q /= q.sum(axis=0, keepdims=True)
        new = q.mean(axis=1)
        if np.abs(new - prior).max() < 1e-6:
            return new
        prior = new
    return prior


def confusion(labels: np.ndarray, pred: np.ndarray) -> np.ndarray:
    keep = labels < C
    return np.bincount(labels[keep].astype(np.int64) * C + pred[keep], minlength=C * C).reshape(
        C, C
    )


def iou(matrix: np.ndarray) -> np.ndarray:
    tp = np.diag(matrix).astype(float)
    return tp / np.maximum(matrix.sum(0) + matrix.sum(1) - tp, 1)


def measure(
    out: Path, model: str, seed: int, sequences: Sequence[str], stride: int, prior_s: np.ndarray
) -> dict[str, Any]:
    path = out / "exports" / f"{model}_s{seed}" / f"{model}_s{seed}.onnx"
    if not path.is_file():
        raise SystemExit(f"{path}: no such exported model")
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    # Unlabelled target training frames: the EM prior. Their labels give the true prior (†).
    pooled, true_count = [], np.zeros(C)
    for folder in sorted((out / "data" / "train" / "target_train").iterdir()):
        for rgb, lab in frames(folder, 10):
            pooled.append(probabilities(session, rgb)[:, ::4, ::4].reshape(C, -1))
            true_count += np.bincount(lab[lab < C].ravel(), minlength=C)[:C]
    prior_em = em_prior(np.concatenate(pooled, axis=1), prior_s)
    prior_true = true_count / true_count.sum()
    weights = {"argmax": np.ones(C), "EM": prior_em / prior_s, "true prior †": prior_true / prior_s}
    matrices = {k: np.zeros((C, C), np.int64) for k in weights}
    for sequence in sequences:
        for rgb, lab in frames(out / "data" / "eval" / sequence, stride):
            p = probabilities(session, rgb)
            for k, w in weights.items():
                matrices[k] += confusion(lab, (p * w[:, None, None]).argmax(axis=0))
    m = matrices["argmax"]
    return {
        "iou": {k: iou(v).tolist() for k, v in matrices.items()},
        "true_fraction": (m.sum(1) / m.sum()).tolist(),
        "predicted_fraction": (m.sum(0) / m.sum()).tolist(),
        "prior_em": prior_em.tolist(),
        "prior_true": prior_true.tolist(),
    }


def report(results: dict[str, dict[int, dict[str, Any]]], prior_s: np.ndarray) -> str:
    def mean(model: str, f) -> np.ndarray:
        return np.mean([f(r) for r in results[model].values()], axis=0)

    names = list(CLASS_NAMES)
    lines = [
        "Per-class IoU on the evaluation sequences, mean over seeds; mIoU with the softmax "
        "re-weighted for a class-prior shift (EM: no labels; true prior †: target labels).",
        "",
        "| model | " + " | ".join(names) + " | mIoU | mIoU, EM prior | mIoU, true prior † |",
        "|---" * (len(names) + 4) + "|",
    ]
    for model in results:
        per = mean(model, lambda r: r["iou"]["argmax"])
        em = mean(model, lambda r: np.mean(r["iou"]["EM"]))
        tp = mean(model, lambda r: np.mean(r["iou"]["true prior †"]))
        cells = " | ".join(f"{v:.3f}" for v in per)
        lines.append(f"| {model} | {cells} | {per.mean():.3f} | {em:.3f} | {tp:.3f} |")
    if "source_only" in results and "oracle" in results:
        so = mean("source_only", lambda r: r["iou"]["argmax"])
        orc = mean("oracle", lambda r: r["iou"]["argmax"])
        gap = (orc - so).sum()
        shares = (
            ", ".join(f"{n} {(o - s) / gap:.0%}" for n, s, o in zip(names, so, orc, strict=True))
            if gap > 0
            else "none (the oracle is not above source-only)"
        )
        lines += [
            "",
            f"Share of the source-only → oracle mIoU gap ({gap / C:.3f}) by class: {shares}.",
        ]
    first = next(iter(results.values()))
    some = next(iter(first.values()))
    fmt = lambda v: " / ".join(f"{x:.3f}" for x in v)  # noqa: E731
    lines += [
        "",
        f"Class fractions ({' / '.join(names)}): source labels {fmt(prior_s)}; target training "
        f"labels † {fmt(some['prior_true'])}; evaluation labels {fmt(some['true_fraction'])}.",
    ]
    for model in results:
        pred = mean(model, lambda r: r["predicted_fraction"])
        em = mean(model, lambda r: r["prior_em"])
        lines.append(f"- {model}: predicted on evaluation {fmt(pred)}; EM prior {fmt(em)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--experiment", type=Path, required=True, help="uss-experiments output")
    parser.add_argument(
        "--models", default="source_only,adabn,adaptsegnet_n5,adaptsegnet_n5_adabn,oracle",
        help="exported model names (without _s<seed>)",
    )  # fmt: skip
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--sequences", default="walking_xyz,walking_rpy")
    parser.add_argument("--stride", type=int, default=10, help="every n-th evaluation frame")
    parser.add_argument("--json", type=Path, help="write every figure here")
    args = parser.parse_args(argv)
    if args.stride < 1:
        parser.error("--stride: expected an integer >= 1")
    out = args.experiment
    seeds = [int(s) for s in args.seeds.split(",")]
    sequences = args.sequences.split(",")
    for s in sequences:
        if not (out / "data" / "eval" / s).is_dir():
            parser.error(f"--sequences: {out / 'data' / 'eval' / s} is not a folder")
    prior_s = source_prior(out)
    results: dict[str, dict[int, dict[str, Any]]] = {}
    for model in args.models.split(","):
        results[model] = {}
        for seed in seeds:
            results[model][seed] = measure(out, model, seed, sequences, args.stride, prior_s)
            r = results[model][seed]
            print(
                f"{model} s{seed}: mIoU {np.mean(r['iou']['argmax']):.3f}, EM "
                f"{np.mean(r['iou']['EM']):.3f}, true prior † "
                f"{statistics.fmean(r['iou']['true prior †']):.3f}",
                file=sys.stderr,
                flush=True,
            )
    print(report(results, prior_s))
    if args.json:
        args.json.write_text(json.dumps({"source_prior": prior_s.tolist(), "results": results}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

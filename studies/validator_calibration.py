"""What is each label-free validator worth? Its calibration on the synthetic demo benchmark, where
target labels exist. Reported in docs/results/validators.md.

1. ``train``: the demo experiment (small DeepLab-v2, 300 iterations from the packaged init) for
   each method x seed, validating every ``--every`` iterations and keeping every validation's
   checkpoint (``data.iterations_per_epoch`` = ``--every``, ``save_top_k=-1``), so that each run
   leaves 300 / every checkpoints, each with the demo's precise source BatchNorm statistics.
2. ``score``: every checkpoint on two target renders: ``val`` (the data set's labelled
   validation sequences, seed 0, every 4th frame: 50) and ``slam`` (the demo's SLAM sequence
   walking_xyz, rendered from another seed, every 20th frame: 15 at 640x480): the validators of
   ``uss_slam.core.validators`` (softmax maps area-averaged to 160 px, as ``uss-eval compare``
   and the training callback feed them) plus ``bn_distance`` against ``--source-frames`` VOC
   images, and the true person IoU and mIoU from the labels. One JSON line per checkpoint in
   ``OUT/scores.jsonl`` (resumable).
3. ``table``: per validator and render, Musgrave's weighted Spearman correlation (power 2) with
   person IoU and with mIoU over every checkpoint of every method and seed; and the person IoU
   that selection by the validator reaches, within each run (the callback's choice of checkpoint)
   and over all checkpoints of a render (choosing among methods too), against the labels' pick
   (the oracle) and against ``last``. Writes ``OUT/calibration.md`` and ``.json``.

    nice -n 10 .venv/bin/python studies/validator_calibration.py all --data outputs/demo/data \
        --out outputs/validator_calibration
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import confusion_matrix
from uss_slam.core.validators import NEEDS_SOURCE, VALIDATORS, build_validators, downsample_maps
from uss_slam.core.verdict import iou_from_matrix, miou, weighted_spearman
from uss_slam.datasets.voc import VOCSegmentation
from uss_slam.export import SegmenterExport, load_checkpoint
from uss_slam.pipelines.assets import demo_init_path
from uss_slam.pipelines.evaluate.frames import sequence_frames
from uss_slam.pipelines.runs import run_training
from uss_slam.train.validation import BatchNormDistance

PERSON = CLASS_NAMES.index("person")
MAX_SIDE = 160
NAMES = ("entropy", "im", "snd", "probe", "dynamic_share", "bn_distance")
LOWER_IS_BETTER = {"probe", "bn_distance"}


def train_runs(data: Path, out: Path, methods: list[str], seeds: list[int], every: int) -> None:
    for method in methods:
        for seed in seeds:
            run = out / "runs" / f"{method}_s{seed}"
            if (run / "done").is_file():
                continue
            t0 = time.perf_counter()
            run_training(run, [
                "experiment=demo", f"model/method={method}", f"seed={seed}",
                f"paths.data_dir={data}", f"run_name=calib_{method}_s{seed}",
                f"model.net.weights_path={demo_init_path()}",
                f"data.iterations_per_epoch={every}", "num_threads=1", "logger=none",
                "callbacks.image_logger=null", "callbacks.target_validators=null",
                "++trainer.enable_progress_bar=false",
                "callbacks.model_checkpoint.save_top_k=-1", "callbacks.model_checkpoint.monitor=null",
                "callbacks.model_checkpoint.filename='iter{iteration:05.0f}'",
            ])  # fmt: skip
            (run / "done").write_text(f"{time.perf_counter() - t0:.0f} s\n")
            print(f"trained {run.name} in {time.perf_counter() - t0:.0f} s", flush=True)


def load_renders(data: Path, val_stride: int = 4, slam_stride: int = 20) -> dict[str, list]:
    val = sequence_frames(sorted((data / "target_val").iterdir()), stride=val_stride)
    slam = sequence_frames([data / "slam" / "walking_xyz"], stride=slam_stride)
    return {"val": list(val.frames()), "slam": list(slam.frames())}


def source_images(data: Path, count: int) -> list[np.ndarray]:
    voc = VOCSegmentation(data / "voc", split="train")
    picks = np.linspace(0, len(voc) - 1, count).astype(int)
    return [voc.load(int(i))["image"].permute(1, 2, 0).numpy() for i in picks]


@torch.no_grad()
def softmax_of(model: torch.nn.Module, images: list[np.ndarray], batch: int = 4):
    """Yield (images' indices, full-size softmax (N, C, H, W) numpy) in batches."""
    for start in range(0, len(images), batch):
        x = torch.from_numpy(np.stack(images[start : start + batch]))
        logits, _ = model(x)
        yield start, F.softmax(logits, dim=1).numpy()


def score_checkpoint(ckpt: Path, renders: dict, source: list[np.ndarray]) -> dict:
    model = SegmenterExport(load_checkpoint(ckpt).segmenter, head="main").eval()
    record: dict = {}
    src_maps = []
    bn = BatchNormDistance(model.segmenter)
    with bn:
        bn.domain("source")
        for _, prob in softmax_of(model, source):
            src_maps.append(downsample_maps(prob, MAX_SIDE))
        source_sums = bn.sums.pop("source")
        for render, frames in renders.items():
            bn.sums = {"source": source_sums}
            bn.domain("target")
            maps = [n for n in NAMES if n in VALIDATORS]
            validators = build_validators(maps)
            for m in src_maps:
                for n in NEEDS_SOURCE & set(validators):
                    validators[n].update_source(m)
            matrix = np.zeros((len(CLASS_NAMES),) * 2, np.int64)
            for start, prob in softmax_of(model, [f.rgb for f in frames]):
                small = downsample_maps(prob, MAX_SIDE)
                for v in validators.values():
                    v.update(small)
                for k, p in enumerate(prob.argmax(axis=1)):
                    matrix += confusion_matrix(frames[start + k].labels, p, len(CLASS_NAMES))
            scores = {n: v.score() for n, v in validators.items()}
            scores["bn_distance"] = bn.score()
            record[render] = {
                "validators": scores,
                "person_iou": float(iou_from_matrix(matrix)[PERSON]),
                "miou": miou(matrix),
            }
    return record


def score_all(data: Path, out: Path, source_count: int, strides: tuple[int, int] = (4, 20)) -> None:
    torch.set_num_threads(1)
    done = set()
    path = out / "scores.jsonl"
    if path.is_file():
        done = {json.loads(line)["checkpoint"] for line in path.read_text().splitlines()}
    renders = load_renders(data, *strides)
    source = source_images(data, source_count)
    ckpts = sorted((out / "runs").glob("*/checkpoints/iter*.ckpt"))
    print(f"{len(ckpts)} checkpoints, {len(done)} scored; renders "
          + ", ".join(f"{k} {len(v)} frames" for k, v in renders.items()), flush=True)  # fmt: skip
    with path.open("a") as f:
        for ckpt in ckpts:
            key = str(ckpt.relative_to(out))
            if key in done:
                continue
            t0 = time.perf_counter()
            method, seed = ckpt.parents[1].name.rsplit("_s", 1)
            row = {"checkpoint": key, "method": method, "seed": int(seed),
                   "iteration": int(ckpt.stem[4:]), **score_checkpoint(ckpt, renders, source)}  # fmt: skip
            f.write(json.dumps(row) + "\n")
            f.flush()
            print(f"{key}: {time.perf_counter() - t0:.1f} s", flush=True)


def signed(name: str, value: float) -> float:
    """Validator score with higher = the validator prefers it."""
    return -value if name in LOWER_IS_BETTER else value


def pick(rows: list[dict], render: str, name: str) -> dict:
    """The row whose ``name`` validator the validator prefers on ``render``."""
    values = [signed(name, r[render]["validators"][name]) for r in rows]
    finite = [v if math.isfinite(v) else -math.inf for v in values]
    return rows[int(np.argmax(finite))]


def gain_vs_last(
    rows: list[dict], runs: list, renders: list[str], name: str, last_iter: int
) -> dict:
    """Person IoU of the validator's pick minus the run's ``last``, per run (mean over the
    renders): mean and 95% Student-t interval over the runs (``name`` ``oracle``: the labels)."""
    from scipy import stats

    gains = []
    for m, s in runs:
        run_rows = [r for r in rows if (r["method"], r["seed"]) == (m, s)]
        last = next(r for r in run_rows if r["iteration"] == last_iter)
        per = []
        for render in renders:
            if name == "oracle":
                best = max(r[render]["person_iou"] for r in run_rows)
            else:
                best = pick(run_rows, render, name)[render]["person_iou"]
            per.append(best - last[render]["person_iou"])
        gains.append(float(np.mean(per)))
    g = np.array(gains)
    half = stats.t.ppf(0.975, len(g) - 1) * g.std(ddof=1) / math.sqrt(len(g))
    return {"mean": float(g.mean()), "low": float(g.mean() - half), "high": float(g.mean() + half),
            "per_run": gains}  # fmt: skip


def table(out: Path) -> dict:
    rows = [json.loads(line) for line in (out / "scores.jsonl").read_text().splitlines()]
    renders = [k for k in rows[0] if isinstance(rows[0][k], dict)]
    runs = sorted({(r["method"], r["seed"]) for r in rows})
    last_iter = max(r["iteration"] for r in rows)
    result: dict = {"checkpoints": len(rows), "runs": [f"{m}_s{s}" for m, s in runs],
                    "renders": renders, "validators": {}}  # fmt: skip
    for name in NAMES:
        entry: dict = {}
        for render in renders:
            v = [signed(name, r[render]["validators"][name]) for r in rows]
            for truth in ("person_iou", "miou"):
                entry.setdefault(f"wspearman_{truth}", []).append(
                    weighted_spearman(v, [r[render][truth] for r in rows])
                )
            within = []
            for m, s in runs:
                run_rows = [r for r in rows if (r["method"], r["seed"]) == (m, s)]
                chosen = pick(run_rows, render, name)
                within.append(chosen[render]["person_iou"])
            entry.setdefault("within_run", []).append(float(np.mean(within)))
            chosen = pick(rows, render, name)
            entry.setdefault("overall", []).append(chosen[render]["person_iou"])
        result["validators"][name] = {k: float(np.mean(v)) for k, v in entry.items()}
        result["validators"][name]["per_render"] = entry
        result["validators"][name]["gain_vs_last"] = gain_vs_last(
            rows, runs, renders, name, last_iter
        )
    ref: dict = {}
    for render in renders:
        oracle_within, last_within = [], []
        for m, s in runs:
            run_rows = [r for r in rows if (r["method"], r["seed"]) == (m, s)]
            oracle_within.append(max(r[render]["person_iou"] for r in run_rows))
            last_within.append(
                next(r for r in run_rows if r["iteration"] == last_iter)[render]["person_iou"]
            )
        ref.setdefault("oracle_within", []).append(float(np.mean(oracle_within)))
        ref.setdefault("last_within", []).append(float(np.mean(last_within)))
        ref.setdefault("oracle_overall", []).append(max(r[render]["person_iou"] for r in rows))
        lasts = [r for r in rows if r["iteration"] == last_iter]
        ref.setdefault("last_overall_mean", []).append(
            float(np.mean([r[render]["person_iou"] for r in lasts]))
        )
    result["reference"] = {k: float(np.mean(v)) for k, v in ref.items()} | {"per_render": ref}
    result["reference"]["oracle_gain_vs_last"] = gain_vs_last(
        rows, runs, renders, "oracle", last_iter
    )
    (out / "calibration.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "calibration.md").write_text(markdown(result))
    print(markdown(result))
    return result


def markdown(r: dict) -> str:
    ref = r["reference"]
    lines = [
        f"{r['checkpoints']} checkpoints ({', '.join(r['runs'])}) x {len(r['renders'])} renders "
        f"({', '.join(r['renders'])}); figures are means over the renders; person IoU in points.",
        "",
        "| validator | wSpearman person IoU | wSpearman mIoU | person IoU, pick per run | "
        "vs last [95% over runs] | vs oracle | person IoU, pick over all |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, v in r["validators"].items():
        g = v["gain_vs_last"]
        lines.append(
            f"| {name} | {v['wspearman_person_iou']:+.2f} | {v['wspearman_miou']:+.2f} | "
            f"{100 * v['within_run']:.1f} | {100 * g['mean']:+.1f} [{100 * g['low']:+.1f}, "
            f"{100 * g['high']:+.1f}] | {100 * (v['within_run'] - ref['oracle_within']):+.1f} | "
            f"{100 * v['overall']:.1f} |"
        )
    lines += [
        f"| `last` | | | {100 * ref['last_within']:.1f} | 0 | "
        f"{100 * (ref['last_within'] - ref['oracle_within']):+.1f} | "
        f"{100 * ref['last_overall_mean']:.1f} (mean of the runs' last) |",
        f"| labels (oracle) | | | {100 * ref['oracle_within']:.1f} | "
        f"{100 * ref['oracle_gain_vs_last']['mean']:+.1f} [{100 * ref['oracle_gain_vs_last']['low']:+.1f}, "
        f"{100 * ref['oracle_gain_vs_last']['high']:+.1f}] | 0 | {100 * ref['oracle_overall']:.1f} |",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("step", choices=("train", "score", "table", "all"))
    parser.add_argument("--data", type=Path, default=Path("outputs/demo/data"))
    parser.add_argument("--out", type=Path, default=Path("outputs/validator_calibration"))
    parser.add_argument("--methods", default="source_only,adaptsegnet")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--every", type=int, default=15)
    parser.add_argument("--source-frames", type=int, default=32)
    parser.add_argument("--val-stride", type=int, default=4, help="every N-th validation frame")
    parser.add_argument("--slam-stride", type=int, default=20, help="every N-th SLAM frame")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.step in ("train", "all"):
        train_runs(args.data.resolve(), args.out.resolve(), args.methods.split(","),
                   [int(s) for s in args.seeds.split(",")], args.every)  # fmt: skip
    if args.step in ("score", "all"):
        score_all(args.data, args.out, args.source_frames, (args.val_stride, args.slam_stride))
    if args.step in ("table", "all"):
        table(args.out)


if __name__ == "__main__":
    main()

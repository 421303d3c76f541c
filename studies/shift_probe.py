"""What does adaptation gain on one synthetic shift at a small budget? The UDA table: in-domain,
source-only (source and target BatchNorm statistics), each method, a target oracle, and each
method's closure. Reported in docs/results/shifts.md (its dated entries) and docs/results/README.md,
"The board" (its 5-seed rows).

Trains (with ``uss-train``, each run reused when its ``last.ckpt`` exists) and scores the
*last* checkpoint of every run (no selection, so no target labels are used to choose it):

- ``source_val``: the VOC tree's ``val`` split (source style; in domain for source-only),
- each ``--test`` folder (labelled frames: a held-out target sequence or image folder), with
  the checkpoint's BatchNorm statistics and also with statistics
  re-estimated on 48 evenly spaced target training frames (AdaBN: row ``adabn`` for
  source-only, ``<method>+adabn`` for the others),

and prints per seed and as mean +- standard error over seeds: mIoU, person IoU and, on the mean
mIoU over the ``--test`` folders paired by seed, the difference to source-only (with its own
statistics) and to AdaBN (with on how many seeds the row is above) and closure =
(method - source-only) / (oracle - source-only) (``--extra`` folders are scored, not in these). ``oracle`` = source-only trained on the
*labelled* target training frames (same network, budget and crops; BatchNorm statistics from
its own training). Data: a ``DemoData`` folder of any shift (``pipelines/synthetic_data.py``).

    .venv/bin/python studies/shift_probe.py --data DATA --test TEST_DIR --runs RUNS \\
        --seeds 0,1 --methods source_only,adaptsegnet,oracle --iters 1200

``--render SHIFT`` renders the data set into ``--data`` first; ``--merge A.json --merge B.json``
writes one table from the ``probe.json`` of runs made apart (e.g. two processes, one per core).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import confusion_matrix, iou_report
from uss_slam.datasets.transforms import eval_transform
from uss_slam.datasets.tum import TUMFrames
from uss_slam.datasets.voc import VOCSegmentation
from uss_slam.export import load_checkpoint
from uss_slam.pipelines.synthetic_data import RECORD, SHIFTS, DemoData, read_spec, render_demo_data
from uss_slam.train.losses import upsample
from uss_slam.train.precise_bn import evenly_spaced, recompute_batchnorm

PERSON = CLASS_NAMES.index("person")
ADABN_IMAGES = 48


FLAGS = {
    # the adversarial term alone: a method's weights scored with source BatchNorm statistics
    "srcbn": ["callbacks.precise_bn.domain=source"],
    # while training, BatchNorm normalises the target batch together with the source batch
    "joint": ["model.domain_batch_norm=joint"],
    # ... or by the running statistics of the source batches, as at evaluation
    "running": ["model.domain_batch_norm=running"],
}
"""Named knobs a row may add to its method: ``adaptsegnet+joint``."""

ADV = (0.002, 0.01)  # the USS-SLAM paper's lambda_adv_aux / lambda_adv_main (model/adversarial)
D_LR = 1e-4  # the discriminators' Adam rate (model/adversarial)
LR = 0.01  # the segmenter's SGD rate of experiment=demo_scratch (its heads get 10x)
ENT = (0.01, 0.05)  # MinEnt's lambda_ent_aux / lambda_ent_main (model/method/minent)
FACTOR = re.compile(r"^(?P<knob>adv|dlr|lr|ent|thr)(?P<factor>[0-9.]+)$")


def knob_overrides(row: str) -> list[str]:
    """The overrides of a row ``<method>[+<knob>]...``: a knob is a name of :data:`FLAGS` or
    ``adv<k>`` / ``dlr<k>`` / ``lr<k>`` / ``ent<k>`` (k times the adversarial weights, the
    discriminators' learning rate, the segmenter's learning rate or MinEnt's weights) or
    ``thr<p>`` (self-training's pseudo-label confidence threshold p), e.g.
    ``adaptsegnet+running+adv10``, ``self_training+thr0.9``."""
    method, *knobs = row.split("+")
    out = [f"model/method={method}"]
    for knob in knobs:
        if knob in FLAGS:
            out += FLAGS[knob]
            continue
        match = FACTOR.match(knob)
        if match is None:
            raise SystemExit(f"--methods: unknown knob {knob!r} in {row!r}; expected one of "
                             f"{', '.join(FLAGS)}, adv<k>, dlr<k>, lr<k>, ent<k>, thr<p>")  # fmt: skip
        k = float(match["factor"])
        if match["knob"] == "adv":
            out += [f"model.method.lambda_adv_aux={ADV[0] * k:g}",
                    f"model.method.lambda_adv_main={ADV[1] * k:g}"]  # fmt: skip
        elif match["knob"] == "dlr":
            out += [f"model.method.d_optimizer.lr={D_LR * k:g}"]
        elif match["knob"] == "lr":
            out += [f"model.optimizer.lr={LR * k:g}"]
        elif match["knob"] == "thr":
            if not 0 < k < 1:
                raise SystemExit(f"--methods: {knob!r} in {row!r}: the threshold must be in (0, 1)")
            out += [f"model.method.pseudo_threshold={k:g}"]
        else:
            out += [f"model.method.lambda_ent_aux={ENT[0] * k:g}",
                    f"model.method.lambda_ent_main={ENT[1] * k:g}"]  # fmt: skip
    return out


def train_overrides(
    data: Path,
    spec: DemoData,
    method: str,
    seed: int,
    iters: int,
    threads: int,
    logger: str = "none",
    init: Path | None = None,
) -> list[str]:
    start = (
        # the demo's warm start: its rate and BatchNorm handling, from the given init
        ["experiment=demo", f"model.net.weights_path={init}"]
        if init is not None
        else ["experiment=demo_scratch"]  # the from-scratch runs of docs/results/shifts.md
    )
    common = [
        *start,
        f"num_threads={threads}",
        f"paths.data_dir={data}",
        f"seed={seed}",
        f"model.max_iters={iters}",
        f"logger={logger}",
        "callbacks.image_logger=null",
        "++trainer.enable_progress_bar=false",
        *spec.train_overrides(data),
    ]
    if method != "oracle":
        return [*common, *knob_overrides(method)]
    roots = ",".join(str(data / f) for f in spec.target_folders())
    return [
        *common,
        "model/method=source_only",
        "data.source._target_=uss_slam.datasets.tum.TUMFrames",
        "~data.source.root",
        "~data.source.split",
        f"+data.source.roots=[{roots}]",
        "+data.source.labels=true",
        "callbacks.precise_bn=null",
    ]


def train(run: Path, overrides: list[str]) -> float:
    """Train into ``run`` unless its last checkpoint exists; returns the CPU seconds spent."""
    if (run / "checkpoints" / "last.ckpt").is_file():
        return 0.0
    start = os.times()
    cmd = [str(Path(sys.executable).parent / "uss-train"), *overrides, f"hydra.run.dir={run}"]
    with open(run.parent / f"{run.name}.log", "w") as log:
        subprocess.run(cmd, check=True, stdout=log, stderr=subprocess.STDOUT)
    end = os.times()
    return end.children_user + end.children_system - start.children_user - start.children_system


def discriminator_accuracy(run: Path) -> dict[str, float]:
    """Mean ``train/d_acc_main`` / ``train/d_acc_aux`` over the last quarter of the logged
    steps of a run trained with ``--logger csv`` (the share of patches whose domain the
    discriminator gets right; 0.5 = chance), or nothing without that log."""
    path = run / "csv" / "metrics.csv"
    if not path.is_file():
        return {}
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    out = {}
    for head in ("main", "aux"):
        logged = [(int(r["step"]), float(r[f"train/d_acc_{head}"])) for r in rows
                  if r.get(f"train/d_acc_{head}")]  # fmt: skip
        if logged:
            last = max(step for step, _ in logged)
            out[f"d_acc_{head}"] = float(np.mean([a for step, a in logged if step >= 0.75 * last]))
    return out


def score(net: torch.nn.Module, dataset: Any) -> dict[str, Any]:
    n = len(CLASS_NAMES)
    matrix = np.zeros((n, n), np.int64)
    with torch.no_grad():
        for i in range(len(dataset)):
            sample = dataset[i]
            labels = sample["label"].numpy()
            logits = upsample(net(sample["image"][None]).main, labels.shape)
            matrix += confusion_matrix(labels, logits.argmax(1)[0].numpy(), n)
    report = iou_report(matrix, CLASS_NAMES)
    return {"mIoU": report["mIoU"], "person": report["IoU"]["person"]}


def mean_se(values: list[float]) -> str:
    values = [v for v in values if v is not None and not math.isnan(v)]
    if not values:
        return "n/a"
    mean = float(np.mean(values))
    if len(values) == 1:
        return f"{mean:.3f}"
    se = float(np.std(values, ddof=1) / math.sqrt(len(values)))
    return f"{mean:.3f} ± {se:.3f}"


def paired(results: dict[str, dict[Any, dict[str, Any]]], name: str, ref: str,
           tests: list[str]) -> str:  # fmt: skip
    """``name`` minus ``ref`` on the mean test mIoU, paired by seed: mean ± s.e. and on how
    many of the seeds both have ``name`` is above."""
    seeds = [s for s in results[name] if s in results.get(ref, {})]
    if name == ref or not seeds:
        return "—"
    diffs = [float(np.mean([results[name][s][t]["mIoU"] for t in tests])
                   - np.mean([results[ref][s][t]["mIoU"] for t in tests])) for s in seeds]  # fmt: skip
    return f"{mean_se(diffs)} ({sum(d > 0 for d in diffs)}/{len(diffs)} above)"


def table(results: dict[str, dict[Any, dict[str, Any]]], sets: list[str],
          tests: list[str]) -> list[str]:  # fmt: skip
    """The markdown table: each set's mIoU and person IoU (mean ± s.e. over seeds), then on the
    mean mIoU over ``tests``, paired by seed: minus source-only, minus AdaBN and the closure
    (row − source-only) / (oracle − source-only); with the discriminators' accuracy over the
    last quarter of training where a run logged it."""
    with_d = any("d_acc_main" in v for per_seed in results.values() for v in per_seed.values())
    header = ("| row | " + " | ".join(f"{k} mIoU | {k} person" for k in sets)
              + " | − source-only | − AdaBN | closure |" + (" D acc main / aux |" * with_d))  # fmt: skip
    lines = [header, "|" + "---|" * (2 * len(sets) + 4 + with_d)]
    for name, per_seed in results.items():
        cells = []
        for key in sets:
            cells.append(mean_se([per_seed[s][key]["mIoU"] for s in per_seed]))
            cells.append(mean_se([per_seed[s][key]["person"] for s in per_seed]))
        closure = []
        if "oracle" in results and "source_only" in results and name != "source_only":
            for s in per_seed:
                if s in results["oracle"] and s in results["source_only"]:
                    lo = np.mean([results["source_only"][s][t]["mIoU"] for t in tests])
                    hi = np.mean([results["oracle"][s][t]["mIoU"] for t in tests])
                    mine = np.mean([per_seed[s][t]["mIoU"] for t in tests])
                    closure.append(float((mine - lo) / (hi - lo)) if hi != lo else float("nan"))
        cells += [
            paired(results, name, "source_only", tests),
            paired(results, name, "adabn", tests),
            mean_se(closure),
        ]
        if with_d:
            heads = [[per_seed[s].get(f"d_acc_{h}") for s in per_seed] for h in ("main", "aux")]
            cells.append(" / ".join(mean_se(v) for v in heads))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def merge(files: list[Path]) -> dict[str, dict[str, dict[str, Any]]]:
    """The rows of several probe.json files, seed by seed."""
    results: dict[str, dict[str, dict[str, Any]]] = {}
    for f in files:
        try:
            data = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise SystemExit(f"--merge {f}: not a readable probe.json ({err})") from None
        if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
            raise SystemExit(f"--merge {f}: expected {{row: {{seed: scores}}}} as probe.json holds")
        for row, per_seed in data.items():
            results.setdefault(row, {}).update(per_seed)
    if not results:
        raise SystemExit("--merge: the files hold no rows")
    return results


def write(runs: Path, results: dict, lines: list[str], title: str) -> None:
    runs.mkdir(parents=True, exist_ok=True)
    (runs / "probe.json").write_text(json.dumps(results, indent=1))
    print("\n".join(lines))
    (runs / "probe.md").write_text("\n".join([title, "", *lines]) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, help="a DemoData folder (with demo.yaml)")
    parser.add_argument(
        "--merge",
        type=Path,
        action="append",
        default=[],
        metavar="JSON",
        help="instead of training and scoring: merge these probe.json files (repeatable; a "
        "row and seed in several: the last wins) into RUNS/probe.json and probe.md",
    )
    parser.add_argument(
        "--render",
        choices=SHIFTS,
        default=None,
        metavar="SHIFT",
        help="render DemoData(shift=SHIFT) into --data first when it holds no data set "
        f"({', '.join(SHIFTS)}; default: use --data as it is)",
    )
    parser.add_argument(
        "--test",
        type=Path,
        action="append",
        required=True,
        help="a labelled target test folder (repeatable; closure is on these)",
    )
    parser.add_argument(
        "--extra",
        type=Path,
        action="append",
        default=[],
        help="a labelled diagnostic folder, scored but not in the closure (e.g. "
        "the test content in the source style)",
    )
    parser.add_argument("--runs", type=Path, required=True,
                        help="one folder per training (<row>_s<seed>, reused when its last.ckpt "
                             "exists), probe.json and probe.md")  # fmt: skip
    parser.add_argument("--seeds", default="0", help="comma-separated (default: 0)")
    parser.add_argument("--methods", default="source_only,adaptsegnet,oracle",
                        help="comma-separated rows: a model/method name, oracle, or a method "
                             "with knobs, <method>+<knob>...: " + ", ".join(FLAGS)
                             + ", adv<k>, dlr<k>, lr<k>, ent<k> (k times the adversarial weights, "
                             "the discriminators' rate, the segmenter's rate, MinEnt's weights), "
                             "thr<p> (self-training's "
                             "pseudo-label threshold p); default: "
                             "source_only,adaptsegnet,oracle)")  # fmt: skip
    parser.add_argument("--iters", type=int, default=1200,
                        help="model.max_iters of every training (default: 1200)")  # fmt: skip
    parser.add_argument("--stride", type=int, default=5, help="every N-th test frame")
    parser.add_argument(
        "--init",
        type=Path,
        default=None,
        help="train every row from this pretrained segmenter (a checkpoint or weights file) "
        "with experiment=demo's settings, instead of from scratch (experiment=demo_scratch)",
    )
    parser.add_argument(
        "--logger",
        default="none",
        help="uss-train's logger of every training (default none; csv keeps train/d_acc_* "
        "and the losses in <run>/csv/)",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=2,
        help="threads of each training and of the scoring (default: 2)",
    )
    args = parser.parse_args()
    tests = [t.name for t in args.test]
    if args.merge:
        results = merge(args.merge)
        for row, per_seed in results.items():
            for seed, scores in per_seed.items():
                base = "source_only" if row == "adabn" else row.removesuffix("+adabn")
                if "d_acc_main" not in scores:
                    scores.update(discriminator_accuracy(args.runs / f"{base}_s{seed}"))
        first = next(iter(next(iter(results.values())).values()))
        sets = [k for k, v in first.items() if isinstance(v, dict) and "mIoU" in v]
        write(args.runs, results, table(results, sets, tests), "merged: " + ", ".join(
            str(m) for m in args.merge))  # fmt: skip
        return
    if args.data is None:
        parser.error("--data is required (unless --merge)")
    torch.set_num_threads(args.threads)
    if args.render is not None and not (args.data / RECORD).is_file():
        render_demo_data(args.data, DemoData(shift=args.render), progress=False)
    if not (args.data / RECORD).is_file():
        raise SystemExit(f"--data {args.data}: no {RECORD} (not a DemoData folder); render one "
                         "with --render SHIFT")  # fmt: skip
    spec = read_spec(args.data)
    seeds = [int(s) for s in args.seeds.split(",")]
    methods = args.methods.split(",")
    args.runs.mkdir(parents=True, exist_ok=True)
    sets = {"source_val": VOCSegmentation(args.data / "voc", split="val",
                                          transform=eval_transform())}  # fmt: skip
    for test in [*args.test, *args.extra]:
        sets[test.name] = TUMFrames([test], labels=True, stride=args.stride,
                                    transform=eval_transform())  # fmt: skip
    target = TUMFrames([args.data / f for f in spec.target_folders()], transform=eval_transform())
    results: dict[str, dict[int, dict[str, Any]]] = {}
    for seed in seeds:
        for method in methods:
            run = args.runs / f"{method}_s{seed}"
            cpu = train(
                run,
                train_overrides(
                    args.data,
                    spec,
                    method,
                    seed,
                    args.iters,
                    args.threads,
                    args.logger,
                    args.init.resolve() if args.init else None,
                ),
            )
            rows = {method: load_checkpoint(run / "checkpoints" / "last.ckpt").segmenter.eval()}
            if method != "oracle":
                # every row also with target statistics (AdaBN on top of the method)
                adabn = load_checkpoint(run / "checkpoints" / "last.ckpt").segmenter.eval()
                indices = evenly_spaced(ADABN_IMAGES, len(target))
                recompute_batchnorm(adabn, target, indices, batch_size=4)
                rows["adabn" if method == "source_only" else f"{method}+adabn"] = adabn
            extra = {"train_cpu_s": cpu} | discriminator_accuracy(run)
            for name, net in rows.items():
                scores = {key: score(net, ds) for key, ds in sets.items()}
                results.setdefault(name, {})[seed] = scores | extra
                print(f"seed {seed} {name:12s} " + " | ".join(
                    f"{k} mIoU {v['mIoU']:.3f} person {v['person']:.3f}"
                    for k, v in scores.items()), flush=True)  # fmt: skip
    title = f"shift {spec.shift}, {args.iters} iterations, last checkpoints, seeds {seeds}"
    write(args.runs, results, table(results, list(sets), tests), title)
    print(f"took {time.process_time():.0f} s CPU in this process")


if __name__ == "__main__":
    main()

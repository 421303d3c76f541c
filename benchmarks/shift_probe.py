"""The UDA table of one synthetic shift at a small budget: in-domain, source-only (source and
target BatchNorm statistics), each method, a target oracle, and each method's closure.

Trains (with ``uss-train``, each run reused when its ``last.ckpt`` exists) and scores the
*last* checkpoint of every run (no selection, so no target labels are used to choose it):

- ``source_val``: the VOC tree's ``val`` split (source style; in domain for source-only),
- each ``--test`` folder (labelled frames: a held-out target sequence or image folder), with
  the checkpoint's BatchNorm statistics and, for ``source_only``, also with statistics
  re-estimated on 48 evenly spaced target training frames (AdaBN, row ``adabn``),

and prints per seed and as mean +- standard error over seeds: mIoU, person IoU and closure =
(method - source-only) / (oracle - source-only) of the mean mIoU over the ``--test`` folders,
paired by seed (source-only with its own statistics as the reference, AdaBN as a method;
``--extra`` folders are scored, not in the closure). ``oracle`` = source-only trained on the
*labelled* target training frames (same network, budget and crops; BatchNorm statistics from
its own training). Data: a ``DemoData`` folder of any shift (``pipelines/demo_data.py``).

    .venv/bin/python benchmarks/shift_probe.py --data DATA --test TEST_DIR --runs RUNS \\
        --seeds 0,1 --methods source_only,adaptsegnet,oracle --iters 1200
"""

from __future__ import annotations

import argparse
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
import yaml

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import confusion_matrix, iou_report
from uss_slam.datasets.transforms import eval_transform
from uss_slam.datasets.tum import TUMFrames
from uss_slam.datasets.voc import VOCSegmentation
from uss_slam.export import load_checkpoint
from uss_slam.pipelines.demo_data import RECORD, DemoData
from uss_slam.train.losses import upsample
from uss_slam.train.precise_bn import evenly_spaced, recompute_batchnorm

PERSON = CLASS_NAMES.index("person")
ADABN_IMAGES = 48


def spec_of(data: Path) -> DemoData:
    record = yaml.safe_load((data / RECORD).read_text())
    return DemoData(
        seed=record["seed"],
        voc_images=record["voc_images"],
        voc_size=tuple(record["voc_size"]),
        train_frames=record["train_frames"],
        val_frames=record["val_frames"],
        train_size=tuple(record["train_size"]),
        slam_frames=record["slam_frames"],
        slam_size=tuple(record["slam_size"]),
        source_outfits=record.get("source_outfits"),
        shift=record.get("shift", "full"),
    )


DIAGNOSTICS = {
    # the adversarial term alone: AdaptSegNet's weights scored with source BatchNorm statistics
    "adaptsegnet+srcbn": ["model/method=adaptsegnet", "callbacks.precise_bn.domain=source"],
}
"""Named rows that vary one knob of a method (``--methods adaptsegnet+srcbn,...``)."""

ADV = (0.002, 0.01)  # the USS-SLAM paper's lambda_adv_aux / lambda_adv_main (model/adversarial)
D_LR = 1e-4  # the discriminators' Adam rate (model/adversarial)
ENT = (0.01, 0.05)  # MinEnt's lambda_ent_aux / lambda_ent_main (model/method/minent)
KNOB = re.compile(r"^(?P<method>[a-z_]+)\+(?P<knob>adv|dlr|ent)(?P<factor>[0-9.]+)$")


def knob_overrides(method: str) -> list[str] | None:
    """``<method>+adv<k>`` / ``+dlr<k>`` / ``+ent<k>``: k times the adversarial weights, the
    discriminators' learning rate or MinEnt's weights (``adaptsegnet+adv10``); None if
    ``method`` is not of that form."""
    match = KNOB.match(method)
    if match is None:
        return None
    base, knob, k = match["method"], match["knob"], float(match["factor"])
    head = [f"model/method={base}"]
    if knob == "adv":
        return [*head, f"model.loss.lambda_adv_aux={ADV[0] * k:g}",
                f"model.loss.lambda_adv_main={ADV[1] * k:g}"]  # fmt: skip
    if knob == "dlr":
        return [*head, f"model.d_optimizer.lr={D_LR * k:g}"]
    return [*head, f"model.method.lambda_ent_aux={ENT[0] * k:g}",
            f"model.method.lambda_ent_main={ENT[1] * k:g}"]  # fmt: skip


def train_overrides(
    data: Path,
    spec: DemoData,
    method: str,
    seed: int,
    iters: int,
    threads: int,
    logger: str = "none",
) -> list[str]:
    common = [
        "experiment=demo",
        f"num_threads={threads}",
        f"paths.data_dir={data}",
        f"seed={seed}",
        f"model.max_iters={iters}",
        f"logger={logger}",
        "callbacks.image_logger=null",
        "++trainer.enable_progress_bar=false",
        *spec.train_overrides(data),
    ]
    if method in DIAGNOSTICS:
        return [*common, *DIAGNOSTICS[method]]
    knob = knob_overrides(method)
    if knob is not None:
        return [*common, *knob]
    if method != "oracle":
        return [*common, f"model/method={method}"]
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, required=True)
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
    parser.add_argument("--runs", type=Path, required=True)
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--methods", default="source_only,adaptsegnet,oracle")
    parser.add_argument("--iters", type=int, default=1200)
    parser.add_argument("--stride", type=int, default=5, help="every N-th test frame")
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
    torch.set_num_threads(args.threads)
    spec = spec_of(args.data)
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
                    args.data, spec, method, seed, args.iters, args.threads, args.logger
                ),
            )
            rows = {method: load_checkpoint(run / "checkpoints" / "last.ckpt").segmenter.eval()}
            if method == "source_only":
                adabn = load_checkpoint(run / "checkpoints" / "last.ckpt").segmenter.eval()
                indices = evenly_spaced(ADABN_IMAGES, len(target))
                recompute_batchnorm(adabn, target, indices, batch_size=4)
                rows["adabn"] = adabn
            for name, net in rows.items():
                scores = {key: score(net, ds) for key, ds in sets.items()}
                results.setdefault(name, {})[seed] = scores | {"train_cpu_s": cpu}
                print(f"seed {seed} {name:12s} " + " | ".join(
                    f"{k} mIoU {v['mIoU']:.3f} person {v['person']:.3f}"
                    for k, v in scores.items()), flush=True)  # fmt: skip
    (args.runs / "probe.json").write_text(json.dumps(results, indent=1))
    header = "| row | " + " | ".join(f"{k} mIoU | {k} person" for k in sets) + " | closure |"
    lines = [f"shift {spec.shift}, {args.iters} iterations, last checkpoints, seeds {seeds}", "",
             header, "|" + "---|" * (2 * len(sets) + 2)]  # fmt: skip
    tests = [t.name for t in args.test]
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
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {mean_se(closure)} |")
    print("\n".join(lines))
    (args.runs / "probe.md").write_text("\n".join(lines) + "\n")
    print(f"took {time.process_time():.0f} s CPU in this process")


if __name__ == "__main__":
    main()

"""How large is the domain gap of the demo data for one ``uss-train`` checkpoint: its mIoU on the
source val, target val and SLAM labels? Reported in docs/results/README.md, "History".

What the README's "The demo experiment, measured" figures come from: mIoU and per-class IoU
(over all four classes, as ``uss-demo``'s ``miou`` stage) of the ``main`` head on

- ``source``: the VOC tree's ``val`` split (source style),
- ``target``: the labelled target validation sequence, every 2nd frame (= ``val/mIoU``),
- ``slam``: every 10th frame of ``slam/walking_xyz`` at its 640x480,

with the checkpoint's BatchNorm statistics, or (``--bn source|target``) statistics re-estimated
over 100 evenly spaced source training images / target training frames first (AdaBN).

    .venv/bin/python studies/demo_domain_gap.py outputs/demo/train/adapted/checkpoints/last.ckpt
    .venv/bin/python studies/demo_domain_gap.py CKPT --data outputs/demo/data --bn target
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import BinaryCounts, confusion_matrix, iou_report, mask_counts
from uss_slam.datasets.transforms import eval_transform
from uss_slam.datasets.tum import TUMFrames
from uss_slam.datasets.voc import VOCSegmentation
from uss_slam.export import load_checkpoint
from uss_slam.train.losses import upsample
from uss_slam.train.precise_bn import evenly_spaced, recompute_batchnorm

TARGET_TRAIN = ("walking_xyz", "walking_rpy", "walking_halfsphere", "sitting_static")


def score(net: torch.nn.Module, dataset: TUMFrames | VOCSegmentation) -> dict:
    n = len(CLASS_NAMES)
    matrix = np.zeros((n, n), np.int64)
    person = BinaryCounts()
    with torch.no_grad():
        for i in range(len(dataset)):
            sample = dataset[i]
            labels = sample["label"].numpy()
            logits = upsample(net(sample["image"][None]).main, labels.shape)
            pred = logits.argmax(1)[0].numpy()
            matrix += confusion_matrix(labels, pred, n)
            person = person + mask_counts(labels, pred, [CLASS_NAMES.index("person")])
    result = iou_report(matrix, CLASS_NAMES)
    rates = person.rates()  # person pixels pooled over the set
    result["person_recall"] = rates["recall"]
    result["person_precision"] = rates["precision"]
    return result


def _fmt(value: float | None) -> str:
    """Three decimals; "n/a" when undefined (class absent, no prediction)."""
    return "n/a" if value is None or value != value else f"{value:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--data", type=Path, default=Path("outputs/demo/data"))
    parser.add_argument("--bn", choices=["checkpoint", "source", "target"], default="checkpoint")
    parser.add_argument("--sets", default="source,target,slam")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    net = load_checkpoint(args.checkpoint).segmenter.eval()
    data = args.data
    if args.bn != "checkpoint":
        if args.bn == "source":
            images = VOCSegmentation(data / "voc", split="train", transform=eval_transform())
        else:
            roots = [data / "target_train" / name for name in TARGET_TRAIN]
            images = TUMFrames(roots, transform=eval_transform())
        count = recompute_batchnorm(net, images, evenly_spaced(100, len(images)), batch_size=4)
        print(f"BatchNorm statistics from {count} {args.bn} images")
    sets = {
        "source": lambda: VOCSegmentation(data / "voc", split="val", transform=eval_transform()),
        "target": lambda: TUMFrames(
            [data / "target_val" / "walking_xyz"], labels=True, stride=2, transform=eval_transform()
        ),
        "slam": lambda: TUMFrames(
            [data / "slam" / "walking_xyz"], labels=True, stride=10, transform=eval_transform()
        ),
    }
    for name in args.sets.split(","):
        result = score(net, sets[name]())
        per_class = " ".join(f"{k} {_fmt(v)}" for k, v in result["IoU"].items())
        print(
            f"{name:7s} mIoU {_fmt(result['mIoU'])} | {per_class} | person recall "
            f"{_fmt(result['person_recall'])} precision {_fmt(result['person_precision'])}"
        )


if __name__ == "__main__":
    main()

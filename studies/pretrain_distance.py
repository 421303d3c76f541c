"""How far is the pretraining set from the source set and from the target frames?

The warm-start protocol starts every row from one init trained on a third synthetic set (``uss-synth
voc --style mixed``), the stand-in for the COCO / ImageNet init users download. This script says
how far that set is from each domain in two ways: the init's segmentation on each domain's
labelled images (mIoU and person IoU: the pretraining set's own val split, the source VOC tree's
val split, the target validation frames), and three image statistics per domain (mean
luminance, the red / blue balance that carries the target's warm cast, and sharpness as the
variance of the Laplacian), each as mean ± standard deviation over the images. Reported in
``docs/results/README.md`` ("The pretrained init").

Usage::

    python studies/pretrain_distance.py --weights INIT.ckpt \\
        --pretrain DIR/VOCdevkit/VOC2012 --source DEMO/data/voc --target DEMO/data/target_val/*
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import confusion_matrix, iou_per_class, mean_iou
from uss_slam.datasets.transforms import eval_transform
from uss_slam.datasets.tum import TUMFrames
from uss_slam.datasets.voc import VOCSegmentation
from uss_slam.models import DeepLabV2

PERSON = CLASS_NAMES.index("person")


def build_model(weights: Path) -> DeepLabV2:
    """The small DeepLab-v2 of ``configs/model/net/deeplab_small.yaml`` with ``weights``."""
    model = DeepLabV2(
        num_classes=len(CLASS_NAMES),
        backbone="resnet_small",
        batchnorm="trained",
        backbone_weights=None,
        weights_path=weights,
    )
    return model.eval()


def image_statistics(rgb: np.ndarray) -> tuple[float, float, float]:
    """``(luminance 0..1, mean red / mean blue, variance of the Laplacian of the grey image)``."""
    rgb = rgb.astype(np.float32) / 255.0
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    balance = float(rgb[..., 0].mean() / max(float(rgb[..., 2].mean()), 1e-6))
    return float(grey.mean()), balance, float(cv2.Laplacian(grey, cv2.CV_32F).var())


@torch.no_grad()
def score(model: DeepLabV2, dataset, limit: int | None) -> dict[str, float]:
    """The model's IoU over the dataset's images, and their image statistics."""
    matrix = np.zeros((len(CLASS_NAMES), len(CLASS_NAMES)), np.int64)
    stats = []
    count = len(dataset) if limit is None else min(limit, len(dataset))
    for index in np.linspace(0, len(dataset) - 1, count).round().astype(int):
        sample = dataset[int(index)]
        image, label = sample["image"], sample["label"].numpy()
        main = model(image[None]).main
        main = torch.nn.functional.interpolate(main, size=label.shape, mode="bilinear")
        matrix += confusion_matrix(label, main.argmax(1)[0].numpy(), len(CLASS_NAMES))
        mean = torch.tensor([0.485, 0.456, 0.406])[:, None, None]
        std = torch.tensor([0.229, 0.224, 0.225])[:, None, None]
        rgb = ((image * std + mean).clamp(0, 1) * 255).byte().permute(1, 2, 0).numpy()
        stats.append(image_statistics(rgb))
    iou = iou_per_class(matrix)
    arr = np.array(stats)
    return {
        "images": int(count),
        "mIoU": round(mean_iou(iou), 4),
        "person_IoU": round(float(iou[PERSON]), 4),
        "luminance": [round(float(arr[:, 0].mean()), 3), round(float(arr[:, 0].std()), 3)],
        "red_blue": [round(float(arr[:, 1].mean()), 3), round(float(arr[:, 1].std()), 3)],
        "sharpness": [round(float(arr[:, 2].mean()), 4), round(float(arr[:, 2].std()), 4)],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--weights", type=Path, required=True, help="the init (checkpoint)")
    parser.add_argument("--pretrain", type=Path, required=True, help="pretraining VOC2012 dir")
    parser.add_argument("--source", type=Path, required=True, help="source VOC tree")
    parser.add_argument("--target", type=Path, nargs="+", required=True,
                        help="labelled target sequences")  # fmt: skip
    parser.add_argument("--limit", type=int, default=120, help="images per domain (spread)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    model = build_model(args.weights)
    transform = eval_transform()
    domains = {
        "pretraining (val)": VOCSegmentation(args.pretrain, split="val", transform=transform),
        "source (val)": VOCSegmentation(args.source, split="val", transform=transform),
        "target (validation frames)": TUMFrames(
            [str(p) for p in args.target], labels=True, transform=transform
        ),
    }
    rows = {name: score(model, data, args.limit) for name, data in domains.items()}
    if args.json:
        json.dump(rows, sys.stdout, indent=2)
        print()
        return 0
    print("| domain | images | mIoU | person IoU | luminance | red / blue | sharpness |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        fmt = " | ".join(f"{m:.3f} ± {s:.3f}" for m, s in (r["luminance"], r["red_blue"]))
        sharp = f"{r['sharpness'][0]:.4f} ± {r['sharpness'][1]:.4f}"
        print(f"| {name} | {r['images']} | {r['mIoU']:.3f} | {r['person_IoU']:.3f} | {fmt} | "
              f"{sharp} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Can a discriminator tell the domains apart from a segmenter's softmax maps at all? Reported in
docs/results/shifts.md, "Why the discriminators stay at chance: BatchNorm while training".

Takes one trained checkpoint and a ``DemoData`` folder, computes the main head's softmax maps
(upsampled to the crop, as AdaptSegNet's discriminator sees them) of random training crops of
both domains, and trains a fresh PatchGAN discriminator on them offline (the segmenter fixed),
then reports its accuracy on held-out crops. The maps are computed as the training step computes
them under each ``model.domain_batch_norm`` (BatchNorm in train mode), and as at evaluation:

- ``separate``: batch statistics of each domain's own batch (two forwards);
- ``joint``: batch statistics of the source and target batch together (one forward);
- ``running``: source by its batch statistics, target by the running statistics;
- ``eval``: both by the checkpoint's running statistics (what scoring and export use).

A discriminator near 0.5 in a mode means the maps of that mode carry no domain signal it can
learn, so the adversarial gradient of a training in that mode has no domain direction.

    .venv/bin/python studies/d_probe.py --data DATA --ckpt RUN/checkpoints/last.ckpt
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from uss_slam.datasets.transforms import train_transform
from uss_slam.datasets.tum import TUMFrames
from uss_slam.datasets.voc import VOCSegmentation
from uss_slam.export import load_checkpoint
from uss_slam.models.discriminator import PatchDiscriminator
from uss_slam.pipelines.synthetic_data import read_spec
from uss_slam.train.losses import SOURCE_LABEL, TARGET_LABEL, domain_accuracy, domain_loss
from uss_slam.train.methods.base import BATCH_NORM_LAYERS

MODES = ("separate", "joint", "running", "eval")
BATCH = 4  # experiment=demo's batch size per domain


def crops(dataset, n: int, rng: np.random.Generator) -> torch.Tensor:
    picks = rng.integers(0, len(dataset), n)
    return torch.stack([dataset[int(i)]["image"] for i in picks])


@torch.no_grad()
def maps(net: torch.nn.Module, src: torch.Tensor, trg: torch.Tensor, mode: str):
    """Softmax maps of the main head for ``src`` / ``trg`` (batches of BATCH), in ``mode``."""
    net = copy.deepcopy(net)
    bns = [m for m in net.modules() if isinstance(m, BATCH_NORM_LAYERS)]
    for m in bns:
        m.momentum = 0.0  # batch statistics in train mode, running ones left as they are

    def run(x: torch.Tensor, batch_statistics: bool) -> torch.Tensor:
        net.train(batch_statistics)
        return net(x).main

    size = src.shape[-2:]
    out_s, out_t = [], []
    for i in range(0, len(src), BATCH):
        s, t = src[i : i + BATCH], trg[i : i + BATCH]
        if mode == "joint":
            main = run(torch.cat([s, t]), True)
            ms, mt = main[: len(s)], main[len(s) :]
        else:
            ms = run(s, mode != "eval")
            mt = run(t, mode == "separate")
        up = lambda x: F.interpolate(x, size=size, mode="bilinear", align_corners=False)  # noqa: E731
        out_s.append(F.softmax(up(ms), 1))
        out_t.append(F.softmax(up(mt), 1))
    return torch.cat(out_s), torch.cat(out_t)


def fit(ms, mt, held_s, held_t, ndf: int, lr: float, steps: int, seed: int) -> dict:
    torch.manual_seed(seed)
    d = PatchDiscriminator(ms.shape[1], n_layers=5, ndf=ndf)
    opt = torch.optim.Adam(d.parameters(), lr=lr, betas=(0.9, 0.99))
    g = torch.Generator().manual_seed(seed)
    train_acc = []
    for step in range(steps):
        i = torch.randint(0, len(ms), (BATCH,), generator=g)
        j = torch.randint(0, len(mt), (BATCH,), generator=g)
        ls, lt = d(ms[i]), d(mt[j])
        loss = domain_loss(ls, SOURCE_LABEL) + domain_loss(lt, TARGET_LABEL)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step >= steps * 3 // 4:
            acc = domain_accuracy(ls.detach(), SOURCE_LABEL) + domain_accuracy(
                lt.detach(), TARGET_LABEL
            )
            train_acc.append(0.5 * float(acc))
    with torch.no_grad():
        held = 0.5 * float(
            domain_accuracy(d(held_s), SOURCE_LABEL) + domain_accuracy(d(held_t), TARGET_LABEL)
        )
    return {"train_acc_last_quarter": float(np.mean(train_acc)), "held_out_acc": held}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="a DemoData folder")
    parser.add_argument("--ckpt", type=Path, required=True, help="a uss-train checkpoint")
    parser.add_argument("--crops", type=int, default=160, help="training crops per domain")
    parser.add_argument("--held", type=int, default=80, help="held-out crops per domain")
    parser.add_argument("--steps", type=int, default=600, help="discriminator steps")
    parser.add_argument("--ndf", default="16,64", help="discriminator widths")
    parser.add_argument("--lr", default="1e-4,1e-3", help="discriminator Adam rates")
    parser.add_argument("--modes", default=",".join(MODES))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, help="write the results as JSON here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    spec = read_spec(args.data)
    transform = train_transform(crop_size=129, scale_range=(0.75, 1.25), hflip=True)
    source = VOCSegmentation(args.data / "voc", split="train", transform=transform)
    target = TUMFrames([args.data / f for f in spec.target_folders()], transform=transform)
    rng = np.random.default_rng(args.seed)
    torch.manual_seed(args.seed)
    n = args.crops + args.held
    src, trg = crops(source, n, rng), crops(target, n, rng)
    net = load_checkpoint(args.ckpt).segmenter
    results = {}
    start = time.process_time()
    for mode in args.modes.split(","):
        ms, mt = maps(net, src, trg, mode)
        conf = (ms.amax(1).mean().item(), mt.amax(1).mean().item())
        for ndf in [int(x) for x in args.ndf.split(",")]:
            for lr in [float(x) for x in args.lr.split(",")]:
                r = fit(ms[: args.crops], mt[: args.crops], ms[args.crops :],
                        mt[args.crops :], ndf, lr, args.steps, args.seed)  # fmt: skip
                r |= {"mean_max_prob_source": conf[0], "mean_max_prob_target": conf[1]}
                results[f"{mode} ndf{ndf} lr{lr:g}"] = r
                print(f"{mode:5s} ndf {ndf:3d} lr {lr:g}: held-out accuracy "
                      f"{r['held_out_acc']:.3f} (train {r['train_acc_last_quarter']:.3f}); "
                      f"mean max prob source {conf[0]:.3f} target {conf[1]:.3f}",
                      flush=True)  # fmt: skip
    print(f"took {time.process_time() - start:.0f} s CPU")
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

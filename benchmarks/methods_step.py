"""How much does each adaptation method cost per training iteration, relative to adaptsegnet,
measured in the same run? Reported in BENCHMARKS.md, "Adaptation methods: CPU per training
iteration".

Every method trains the same segmenter from the same initial state on the same fixed random batch
under a Lightning Trainer that logs like ``uss-train``
(:func:`uss_slam.testing.step_timing.time_lightning`, as ``benchmarks/train_step.py``); the
methods are interleaved and rotated per repeat so that each sees the same machine load. Default
shapes are the demo experiment's: the small backbone, 129-pixel crops, batch 4 per domain,
BatchNorm trained, discriminators of width 16.

    .venv/bin/python benchmarks/methods_step.py                      # both small nets, CPU clock
    .venv/bin/python benchmarks/methods_step.py --nets deeplab_small --iters 10 --repeats 5
    .venv/bin/python benchmarks/methods_step.py --clock wall --threads 2

``--clock cpu`` (default) times with the process's CPU time: on a shared machine with one thread
that is what an iteration costs, whatever the other jobs do.
"""

from __future__ import annotations

import argparse
import copy
import functools
import logging
import statistics
import time
from collections.abc import Callable
from typing import Any

import torch

from uss_slam.models import DeepLabV2, PatchDiscriminator, PSPNet
from uss_slam.testing.reference_step import random_batch
from uss_slam.testing.step_timing import time_lightning
from uss_slam.train.losses import LossWeights
from uss_slam.train.methods import AdaptSegNet, AdvEnt, Method, MinEnt, SelfTraining, SourceOnly
from uss_slam.train.module import AdversarialSegmentation

NETS: dict[str, Callable[[bool], torch.nn.Module]] = {
    "deeplab_small": lambda freeze: DeepLabV2(4, "resnet_small", freeze_bn=freeze),
    "pspnet_small": lambda freeze: PSPNet(4, "resnet_small", freeze_bn=freeze),
}


def discriminators(ndf: int) -> dict[str, Any]:
    """AdaptSegNet's / ADVENT's discriminators (depth 5, width ``ndf``) and their Adam."""
    return {
        "discriminator": functools.partial(PatchDiscriminator, 4, 5, ndf),
        "d_optimizer": functools.partial(torch.optim.Adam, lr=1e-4, betas=(0.9, 0.99)),
    }


METHODS: dict[str, Callable[[torch.nn.Module, int], Method]] = {
    "source_only": lambda net, ndf: SourceOnly(),
    "adaptsegnet": lambda net, ndf: AdaptSegNet(**discriminators(ndf)),
    "advent": lambda net, ndf: AdvEnt(
        **discriminators(ndf), lambda_adv_aux=0.0002, lambda_adv_main=0.001
    ),
    "minent": lambda net, ndf: MinEnt(),
    "self_training": lambda net, ndf: SelfTraining(copy.deepcopy(net)),
}


def build(net_name: str, method: str, freeze_bn: bool, ndf: int) -> AdversarialSegmentation:
    torch.manual_seed(0)
    net = NETS[net_name](freeze_bn)
    module = AdversarialSegmentation(
        net=net,
        optimizer=functools.partial(
            torch.optim.SGD, lr=2.5e-4, momentum=0.9, nesterov=True, weight_decay=1e-4
        ),
        method=METHODS[method](net, ndf),
        loss=LossWeights(),
        max_iters=10_000,
        channels_last=True,
    )
    return module


def run(net_name: str, size: int, batch_size: int, iters: int, repeats: int, args) -> None:  # noqa: ANN001
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    batch = random_batch(size, batch_size)
    batch["source"]["label"] = torch.randint(0, 4, batch["source"]["label"].shape)
    results: dict[str, list[float]] = {m: [] for m in METHODS}
    names = list(METHODS)
    for repeat in range(repeats):
        for name in names[repeat % len(names) :] + names[: repeat % len(names)]:
            module = build(net_name, name, args.freeze_bn, args.ndf)
            # The first iteration of each run is a warm-up.
            results[name] += time_lightning(module, batch, iters + 1, clock=clock)[1:]
    base = statistics.median(results["adaptsegnet"])
    bn = "frozen BN" if args.freeze_bn else "BN trained"
    print(
        f"{net_name} {size}x{size} batch {batch_size} ({bn}, D ndf {args.ndf}, channels-last), "
        f"median {args.clock} s/iteration over {iters * repeats} iterations each"
    )
    for name, times in results.items():
        median = statistics.median(times)
        print(f"  {name:14s} {median:8.4f} s/it   vs adaptsegnet {median / base:6.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nets", nargs="+", default=list(NETS), choices=list(NETS))
    parser.add_argument("--size", type=int, default=129)
    parser.add_argument("--batch", type=int, default=4)
    parser.add_argument("--iters", type=int, default=5, help="timed iterations per repeat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--ndf", type=int, default=16)
    parser.add_argument("--freeze-bn", action="store_true", help="frozen BN (the paper's)")
    parser.add_argument("--clock", choices=["cpu", "wall"], default="cpu")
    args = parser.parse_args()
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {args.threads} thread(s), {args.clock} clock")
    for net_name in args.nets:
        run(net_name, args.size, args.batch, args.iters, args.repeats, args)


if __name__ == "__main__":
    main()

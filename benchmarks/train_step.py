"""What does the Lightning module cost per training iteration against a plain-PyTorch loop of the
same computation, in the same run, and what do its speed options (``--suite speed``: compile,
channels-last, bf16, fused optimisers) gain? Reported in BENCHMARKS.md, "Training iteration" and
"Training speed options".

One iteration = the paper's Algorithm 1: source and target forward, segmentation and
adversarial losses, segmenter step, both discriminator updates. Both loops train the same
weights from the same initial state on the same fixed batch; the script checks that they
end with the same weights (so they compute the same thing) and reports the median seconds per
iteration of each and the ratio Lightning / plain.

    .venv/bin/python benchmarks/train_step.py                      # ResNet-101 321x321 + demo
    .venv/bin/python benchmarks/train_step.py --models small --iters 20
    .venv/bin/python benchmarks/train_step.py --clock cpu --threads 1   # busy machine
    .venv/bin/python benchmarks/train_step.py --models tiny   # Lightning's fixed cost, in ms

``--suite speed`` times the module's speed options against the eager module (``eager`` = the
shipped defaults) and the plain loop, same run: ``compile`` (``model.compile``),
``channels_last``, ``bf16`` (``trainer.precision=bf16-mixed``), ``fused``
(``model.optimizer_kernels=fused``), ``fast`` (the settings of ``trainer=fast_cpu``) and
``fast+compile`` (``trainer=fast_cpu model.compile=true``). Each
variant trains one instance across the repeats (compiled networks compile once; that cost is
reported separately, not in the median, with a cold inductor cache unless ``--warm-cache``), and
after the timing each variant's losses and weights after 2 iterations from the same start are
compared with ``eager``'s.

    .venv/bin/python benchmarks/train_step.py --suite speed --models resnet101 small

``--clock cpu`` times with the process's CPU time (all threads) instead of the wall clock: on a
shared machine the wall clock measures the other jobs; with one thread CPU time does not.

The Lightning variants run under a Trainer that logs like ``uss-train``: TensorBoard (into a
temporary folder) every 10 steps; ``--progress-bar`` adds the TQDM bar of an interactive run.

The plain loop is :func:`uss_slam.testing.reference_step.plain_iteration`, the independent
reference the step tests compare the module with.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import logging
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from uss_slam.models import DeepLabV2
from uss_slam.testing.machine import cpu_model
from uss_slam.testing.reference_step import (
    PaperWeights,
    PlainState,
    build_module,
    calibrate_batchnorm,
    max_difference,
    plain_iteration,
    plain_state_from,
    random_batch,
    weights_of,
)
from uss_slam.testing.step_timing import FAST_CPU, Speed, time_lightning
from uss_slam.train.module import AdversarialSegmentation
from uss_slam.train.speed import BF16_FLAGS, cpu_flags

CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}
clock = time.perf_counter
progress_bar = False


def time_plain(state: PlainState, batch: dict, iters: int, weights: PaperWeights) -> list[float]:
    times = []
    for _ in range(iters):
        start = clock()
        plain_iteration(state, batch, weights)
        times.append(clock() - start)
    return times


COMPARED = "lightning (--compare-module)"
VARIANTS = {
    # name: (batch_domains, channels_last)
    "lightning": (False, False),  # Algorithm 1 step by step, as the plain loop
    "lightning+nhwc": (False, True),
    "lightning+batched": (True, False),
    "lightning+batched+nhwc": (True, True),
}


@dataclass(frozen=True)
class Case:
    """One benchmarked network and shape: ``repeats`` x ``iters`` timed iterations per variant
    on ``batch_size`` random ``size`` x ``size`` images, discriminators of width ``ndf``."""

    backbone: str
    size: int
    batch_size: int
    iters: int
    repeats: int
    ndf: int
    batchnorm: str = "frozen"  # model.net.batchnorm: frozen, trained or reference

    @property
    def freeze_bn(self) -> bool:
        return self.batchnorm == "frozen"

    def start(self) -> tuple[AdversarialSegmentation, dict]:
        """The seeded module and fixed random batch every variant starts from (BatchNorm
        statistics calibrated on the batch)."""
        torch.manual_seed(0)
        module = build_module(self.backbone, ndf=self.ndf, freeze_bn=self.freeze_bn)
        if self.batchnorm == "reference":  # same weights, AdaptSegNet's BatchNorm
            net = DeepLabV2(4, self.backbone, batchnorm="reference")
            net.load_state_dict(module.segmenter.state_dict())
            module.segmenter = net
        batch = random_batch(self.size, self.batch_size)
        calibrate_batchnorm(
            module.segmenter, torch.cat([batch["source"]["image"], batch["target"]["image"]])
        )
        return module, batch

    def heading(self, bn: str) -> str:
        """The first words of the case's table: network, shape and ``bn`` (the BatchNorm mode)."""
        return (
            f"{self.backbone} {self.size}x{self.size} batch {self.batch_size} "
            f"(D ndf {self.ndf}, {bn})"
        )


def cases(args: argparse.Namespace) -> list[Case]:
    """The ``--models`` of the command line: ``small`` the demo experiment's shapes, ``tiny``
    the small network at 33x33 and batch 1, the ResNets the paper's. BatchNorm: ``--batchnorm``,
    else frozen for the small network and the paper's ``reference`` for the ResNets (a random
    ResNet-101 under frozen BatchNorm diverges within a few iterations, even with statistics
    calibrated on the batch: the loop would time NaN arithmetic)."""
    chosen = "trained" if args.train_bn else args.batchnorm
    out = []
    for name in args.models:
        if name == "small":
            bn = chosen or "frozen"
            out.append(Case("resnet_small", 129, 4, args.iters * 4, args.repeats, 16, bn))
        elif name == "tiny":
            bn = chosen or "frozen"
            out.append(Case("resnet_small", 33, 1, args.iters * 20, args.repeats, 16, bn))
        else:
            out.append(Case(name, 321, 1, args.iters, args.repeats, 64, chosen or "reference"))
    return out


def run(case: Case, compare: type[AdversarialSegmentation] | None = None) -> None:
    module, batch = case.start()
    weights = weights_of(module)
    results: dict[str, list[float]] = {"plain": [], **{name: [] for name in VARIANTS}}
    if compare is not None:
        results[COMPARED] = []
    names = list(results)
    for repeat in range(case.repeats):
        # Interleaved, and in a rotated order each repeat: every variant sees the same machine
        # load and none always runs first or last. The first iteration of a run is a warm-up.
        for name in names[repeat % len(names) :] + names[: repeat % len(names)]:
            if name == "plain":
                state = plain_state_from(module)
                results["plain"] += time_plain(state, batch, case.iters, weights)[1:]
                continue
            variant = copy.deepcopy(module)
            if name == COMPARED:  # same weights and settings as `lightning`, other class
                variant.__class__ = compare
                settings = VARIANTS["lightning"]
            else:
                settings = VARIANTS[name]
            variant.batch_domains, variant.channels_last = settings
            results[name] += time_lightning(
                variant, batch, case.iters, clock=clock, progress_bar=progress_bar
            )[1:]
    # Same computation: from the same start, module and plain loop end with the same weights.
    check_module = copy.deepcopy(module)
    check_module.batch_domains = False
    check_state = plain_state_from(check_module)
    time_lightning(check_module, batch, 2, clock=clock, progress_bar=progress_bar)
    for _ in range(2):
        plain_iteration(check_state, batch, weights)
    diff = max_difference(check_module.segmenter, check_state.segmenter)
    if not all(torch.isfinite(p).all() for p in check_state.segmenter.parameters()):
        raise SystemExit(f"{case.backbone}: the plain loop produced non-finite weights")
    plain = statistics.median(results["plain"])
    base = statistics.median(results["lightning"])
    bn = "frozen BN" if case.freeze_bn else f"BN {case.batchnorm} (batched variants run unbatched)"
    print(
        f"{case.heading(bn)}, median s/iteration over "
        f"{len(results['plain'])} iterations each; segmenter max |difference| module vs plain "
        f"after 2 iterations: {diff:.1e}"
    )
    for name, times in results.items():
        median = statistics.median(times)
        print(
            f"  {name:30s} {median:8.4f} s/it   vs plain {median / plain:6.3f} "
            f"({1000 * (median - plain):+6.1f} ms)   vs lightning {median / base:6.3f}"
        )


SPEED_VARIANTS = {
    "eager": Speed(),  # the shipped defaults: batched domains, NCHW, float32, eager
    "compile": Speed({"compile_networks": True}),
    "channels_last": Speed({"channels_last": True}),
    "bf16": Speed(precision="bf16-mixed"),
    "fused": Speed({"optimizer_kernels": "fused"}),
    "fast": FAST_CPU,
    "fast+compile": Speed({**FAST_CPU.settings, "compile_networks": True}, FAST_CPU.precision),
}


def speed_variant(module: AdversarialSegmentation, speed: Speed) -> AdversarialSegmentation:
    variant = copy.deepcopy(module)
    for name, value in speed.settings.items():
        if not hasattr(variant, name):
            raise AttributeError(f"AdversarialSegmentation has no {name}")
        setattr(variant, name, value)
    return variant


def _restart(variant: AdversarialSegmentation, start: AdversarialSegmentation) -> None:
    """Back to ``start``'s weights and iteration 0 (the next fit builds fresh optimisers)."""
    variant.load_state_dict(start.state_dict())
    variant.iteration = 0


def run_speed(case: Case, variants: list[str] | None = None) -> None:
    module, batch = case.start()
    weights = weights_of(module)
    speeds = {name: SPEED_VARIANTS[name] for name in variants or SPEED_VARIANTS}
    # One instance per variant for the whole run: compiled networks compile in its first fit.
    instances = {name: speed_variant(module, speed) for name, speed in speeds.items()}
    first: dict[str, float] = {}
    results: dict[str, list[float]] = {"plain": [], **{name: [] for name in speeds}}
    # Each repeat's median too: the spread between repeats shows an outlier that the pooled
    # median hides.
    repeat_medians: dict[str, list[float]] = {name: [] for name in results}
    names = list(results)
    state = plain_state_from(module)
    for repeat in range(case.repeats):
        for name in names[repeat % len(names) :] + names[: repeat % len(names)]:
            if name == "plain":
                timed = time_plain(state, batch, case.iters, weights)[1:]
            else:
                times = time_lightning(
                    instances[name], batch, case.iters, speeds[name].precision, clock=clock
                )
                first.setdefault(name, times[0])
                timed = times[1:]
            results[name] += timed
            repeat_medians[name].append(statistics.median(timed))
            # A ResNet-101 suite runs for tens of minutes on a busy CPU: say where it is.
            print(
                f"{case.backbone}: repeat {repeat + 1}/{case.repeats} {name} "
                f"{repeat_medians[name][-1]:.4f} s/it",
                file=sys.stderr,
                flush=True,
            )
    # Same computation: 2 iterations of every variant from the same start, against eager.
    losses: dict[str, list[dict[str, float]]] = {}
    finals: dict[str, dict[str, Tensor]] = {}
    for name, variant in instances.items():
        _restart(variant, module)
        losses[name] = []
        time_lightning(variant, batch, 2, speeds[name].precision, losses[name], clock=clock)
        finals[name] = {k: v.detach().float().clone() for k, v in variant.state_dict().items()}
    plain = statistics.median(results["plain"])
    eager = statistics.median(results["eager"]) if "eager" in results else None
    bn = "frozen BN" if case.freeze_bn else f"BN {case.batchnorm} (domains unbatched)"
    print(
        f"{case.heading(bn)}: median s/iteration "
        f"over {case.iters - 1} x {case.repeats} iterations each (the first of each fit excluded)"
    )
    print(
        f"  {'variant':14s} {'s/it':>8s} {'vs plain':>9s} {'vs eager':>9s} {'compile s':>10s} "
        f"{'repeats min-max':>16s} {'max |dloss|/loss':>17s} {'max |dweight|':>14s}"
    )
    for name, times in results.items():
        median = statistics.median(times)
        compiled = speeds[name].settings.get("compile_networks") if name in speeds else False
        compile_s = instances[name].compile_seconds if compiled else None
        if compiled and compile_s is None:  # fewer than 2 iterations per fit
            compile_s = first[name] - median
        loss_diff = weight_diff = "-"
        if name in losses and "eager" in losses and name != "eager":
            loss_diff = f"{_max_relative(losses[name], losses['eager']):.1e}"
            weight_diff = f"{_max_abs(finals[name], finals['eager']):.1e}"
        spread = f"{min(repeat_medians[name]):.4f}-{max(repeat_medians[name]):.4f}"
        print(
            f"  {name:14s} {median:8.4f} {median / plain:9.3f} "
            f"{'-' if eager is None else f'{median / eager:.3f}':>9s} "
            f"{'-' if compile_s is None else f'{compile_s:.1f}':>10s} {spread:>16s} "
            f"{loss_diff:>17s} {weight_diff:>14s}"
        )


def _max_relative(a: list[dict[str, float]], b: list[dict[str, float]]) -> float:
    return max(
        abs(x[k] - y[k]) / max(abs(y[k]), 1e-12)
        for x, y in zip(a, b, strict=True)
        for k in y
        if k.startswith("train/loss")
    )


def _max_abs(a: dict[str, Tensor], b: dict[str, Tensor]) -> float:
    return max(float((a[k] - b[k]).abs().max()) for k in b if b[k].is_floating_point())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--models",
        nargs="+",
        default=["resnet101", "small"],
        choices=["resnet101", "resnet50", "small", "tiny"],
        help="small: the demo's shapes; tiny: the small model at 33x33, batch 1, where compute "
        "is negligible and the difference to plain is Lightning's fixed cost per iteration",
    )
    parser.add_argument(
        "--suite",
        choices=["lightning", "speed"],
        default="lightning",
        help="lightning: the module's overhead over plain PyTorch (the batched / channels-last "
        "variants); speed: compile, channels-last, bf16, fused optimisers and their "
        "combination (trainer=fast_cpu) against the eager module",
    )
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=list(SPEED_VARIANTS),
        help="--suite speed: only these variants (default: all)",
    )
    parser.add_argument(
        "--warm-cache",
        action="store_true",
        help="--suite speed: keep inductor's compile cache (default: a fresh one, so the "
        "compile time is that of a first run)",
    )
    parser.add_argument("--iters", type=int, default=6, help="iterations per repeat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--clock", choices=sorted(CLOCKS), default="wall", help="wall clock or process CPU time"
    )
    parser.add_argument(
        "--train-bn",
        action="store_true",
        help="same as --batchnorm trained (the demo experiment's BatchNorm)",
    )
    parser.add_argument(
        "--batchnorm",
        choices=["frozen", "trained", "reference"],
        help="model.net.batchnorm of every case (default: frozen for small / tiny, reference "
        "for the ResNets, the paper's)",
    )
    parser.add_argument(
        "--compare-module",
        type=Path,
        help="a train/module.py of another version (e.g. `git show REV:train/module.py > "
        "/tmp/old.py`): its AdversarialSegmentation is timed as one more variant, same run",
    )
    parser.add_argument(
        "--progress-bar",
        action="store_true",
        help="time the Lightning variants with the TQDM progress bar (interactive uss-train)",
    )
    args = parser.parse_args()
    if args.iters < 2 or args.repeats < 1:
        parser.error(
            f"--iters must be at least 2 (the first iteration of each fit is a warm-up, not "
            f"timed) and --repeats at least 1, got --iters {args.iters} --repeats {args.repeats}"
        )
    if args.suite == "speed":
        return main_speed(args)
    global clock, progress_bar
    clock = CLOCKS[args.clock]
    progress_bar = args.progress_bar
    # Lightning's per-Trainer banners ("GPU available", tips) would bury the table.
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {args.threads} threads, {args.clock} clock")
    compare = None
    if args.compare_module is not None:
        spec = importlib.util.spec_from_file_location("compared_module", args.compare_module)
        compared = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(compared)
        compare = compared.AdversarialSegmentation
    for case in cases(args):
        run(case, compare)


def main_speed(args: argparse.Namespace) -> None:
    global clock
    clock = CLOCKS[args.clock]
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory(prefix="inductor_") as cache:
        if not args.warm_cache:
            os.environ["TORCHINDUCTOR_CACHE_DIR"] = cache
        bf16 = sorted(flag for flag in BF16_FLAGS if flag in cpu_flags()) or ["none"]
        print(
            f"{cpu_model()} (bfloat16 instructions: {', '.join(bf16)}), torch "
            f"{torch.__version__}, {args.threads} threads, {args.clock} clock, "
            f"{'warm' if args.warm_cache else 'cold'} compile cache"
        )
        print(f"{time.strftime('%Y-%m-%d %H:%M', time.gmtime())} UTC, load {_load()}")
        for case in cases(args):
            run_speed(case, args.variants)
        print(f"{time.strftime('%Y-%m-%d %H:%M', time.gmtime())} UTC, load at the end {_load()}")


def _load() -> str:
    """The 1-, 5- and 15-minute load averages."""
    return " / ".join(f"{x:.1f}" for x in os.getloadavg())


if __name__ == "__main__":
    main()

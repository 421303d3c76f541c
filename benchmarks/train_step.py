"""Seconds per training iteration: the Lightning module vs a plain-PyTorch loop, same run;
with ``--suite speed``, the speed options (compile, channels-last, bf16, fused optimisers).

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

:func:`plain_iteration` is also the independent reference the tests compare the module with.
"""

from __future__ import annotations

import argparse
import copy
import functools
import importlib.util
import logging
import os
import statistics
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from uss_slam.models import DeepLabV2, PatchDiscriminator
from uss_slam.train.losses import LossWeights
from uss_slam.train.methods import StepValues
from uss_slam.train.module import AdversarialSegmentation
from uss_slam.train.schedules import PolyLR


@dataclass
class PlainState:
    """Everything a plain training loop owns."""

    segmenter: DeepLabV2
    d_aux: nn.Module
    d_main: nn.Module
    opt_seg: torch.optim.Optimizer
    opt_d: torch.optim.Optimizer
    sched_seg: PolyLR
    sched_d: PolyLR


def _up(logits: Tensor, size: torch.Size) -> Tensor:
    return F.interpolate(logits, size=size, mode="bilinear", align_corners=True)


def _bce(logits: Tensor, label: float) -> Tensor:
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, label))


def source_loss(
    segmenter: nn.Module, batch: dict, weights: LossWeights, out_src: Any = None
) -> tuple[Tensor, Tensor, Tensor]:
    """The weighted cross-entropy of both heads on the source images, and the two heads' logits
    upsampled to the labels (``aux``, ``main``); ``out_src``: the segmenter's output on the
    source images when already computed."""
    src_img, src_lbl = batch["source"]["image"], batch["source"]["label"]
    if out_src is None:
        out_src = segmenter(src_img)
    up_aux, up_main = _up(out_src.aux, src_lbl.shape[-2:]), _up(out_src.main, src_lbl.shape[-2:])
    loss_seg = weights.lambda_seg_aux * F.cross_entropy(
        up_aux, src_lbl, ignore_index=255
    ) + weights.lambda_seg_main * F.cross_entropy(up_main, src_lbl, ignore_index=255)
    return loss_seg, up_aux, up_main


def plain_iteration(
    state: PlainState,
    batch: dict,
    weights: LossWeights,
    adaptation: bool = True,
    domain_batch_norm: str = "separate",
) -> None:
    """Algorithm 1 written out in plain PyTorch (independent of the Lightning module).
    ``domain_batch_norm`` (BatchNorm in train mode): ``separate`` = one forward per domain,
    ``joint`` = source and target images through one forward (both batches' statistics),
    ``running`` = the target forward with BatchNorm in eval mode (running statistics)."""
    joint_batch_norm = domain_batch_norm == "joint"
    seg, d_aux, d_main = state.segmenter, state.d_aux, state.d_main
    src_img, trg_img = batch["source"]["image"], batch["target"]["image"]
    out_src = out_trg = None
    if adaptation and joint_batch_norm:
        n = src_img.shape[0]
        both = seg(torch.cat([src_img, trg_img]))
        out_src = type(both)(both.aux[:n], both.main[:n])
        out_trg = type(both)(both.aux[n:], both.main[n:])

    # (1) segmentation loss, discriminators frozen.
    for p in _params(d_aux, d_main):
        p.requires_grad_(False)
    state.opt_seg.zero_grad()
    loss_seg, up_aux, up_main = source_loss(seg, batch, weights, out_src)
    if out_trg is None:
        loss_seg.backward()  # the source graph is freed before the target forward
    if adaptation:
        # (2) adversarial loss: target outputs should look like source (label 0).
        if out_trg is None and domain_batch_norm == "running":
            bns = [m for m in seg.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
            for m in bns:
                m.eval()
            out_trg = seg(trg_img)
            for m in bns:
                m.train()
        elif out_trg is None:
            out_trg = seg(trg_img)
        p_aux = F.softmax(_up(out_trg.aux, trg_img.shape[-2:]), dim=1)
        p_main = F.softmax(_up(out_trg.main, trg_img.shape[-2:]), dim=1)
        loss_adv = weights.lambda_adv_aux * _bce(d_aux(p_aux), 0.0)
        loss_adv = loss_adv + weights.lambda_adv_main * _bce(d_main(p_main), 0.0)
        if joint_batch_norm:
            loss_adv = loss_adv + loss_seg  # one graph for both domains: one backward
        loss_adv.backward()
    state.opt_seg.step()
    for p in _params(d_aux, d_main):
        p.requires_grad_(True)

    if adaptation:
        # (3) + (4) discriminators: detached source = 0, target = 1.
        state.opt_d.zero_grad()
        src_aux, src_main = F.softmax(up_aux.detach(), 1), F.softmax(up_main.detach(), 1)
        (_bce(d_aux(src_aux), 0.0) + _bce(d_main(src_main), 0.0)).backward()
        (_bce(d_aux(p_aux.detach()), 1.0) + _bce(d_main(p_main.detach()), 1.0)).backward()
        state.opt_d.step()
        state.sched_d.step()
    state.sched_seg.step()


def _params(*modules: nn.Module) -> Iterator[nn.Parameter]:
    for module in modules:
        yield from module.parameters()


def plain_state_from(module: AdversarialSegmentation) -> PlainState:
    """Deep copies of the module's networks with freshly built optimisers and schedules."""
    seg = copy.deepcopy(module.segmenter)
    d_aux, d_main = copy.deepcopy(module.d_aux), copy.deepcopy(module.d_main)
    lr = module.optimizer_factory.keywords["lr"]
    opt_seg = module.optimizer_factory(params=seg.param_groups(lr, module.head_lr_mult))
    opt_d = module.d_optimizer_factory(params=list(d_aux.parameters()) + list(d_main.parameters()))
    return PlainState(
        seg,
        d_aux,
        d_main,
        opt_seg,
        opt_d,
        PolyLR(opt_seg, module.poly_total_iters, module.poly_power),
        PolyLR(opt_d, module.poly_total_iters, module.poly_power),
    )


def build_module(
    backbone: str, max_iters: int = 1000, n_layers: int = 5, ndf: int = 64, freeze_bn: bool = True
) -> AdversarialSegmentation:
    return AdversarialSegmentation(
        net=DeepLabV2(num_classes=4, backbone=backbone, freeze_bn=freeze_bn),
        discriminator=functools.partial(PatchDiscriminator, 4, n_layers, ndf),
        optimizer=functools.partial(
            torch.optim.SGD, lr=2.5e-4, momentum=0.9, nesterov=True, weight_decay=1e-4
        ),
        d_optimizer=functools.partial(torch.optim.Adam, lr=1e-4, betas=(0.9, 0.99)),
        max_iters=max_iters,
    )


@torch.no_grad()
def calibrate_batchnorm(net: nn.Module, images: Tensor) -> None:
    """Set every BatchNorm's running statistics from ``images`` (one cumulative pass), as
    pretrained weights would have them. A randomly initialised ResNet-101 whose frozen BN keeps
    the default statistics (mean 0, var 1) normalises nothing and diverges at the first step:
    the loop would then time NaN arithmetic."""
    was_training = net.training
    bns = [m for m in net.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    for bn in bns:
        bn.reset_running_stats()
        bn.momentum = None  # cumulative average
        bn.train()
    net(images)
    for bn in bns:
        bn.momentum = 0.1
    net.train(was_training)  # DeepLabV2.train re-freezes BN when freeze_bn is set


def random_batch(size: int, batch: int = 1, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    label = torch.randint(0, 4, (batch, size, size), generator=g)
    label[:, :4] = 255
    return {
        "source": {"image": torch.randn(batch, 3, size, size, generator=g), "label": label},
        "target": {"image": torch.randn(batch, 3, size, size, generator=g)},
    }


class _Repeat(torch.utils.data.Dataset):
    def __init__(self, batch: dict, n: int) -> None:
        self.batch, self.n = batch, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int) -> dict:
        return self.batch


CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}
clock = time.perf_counter
progress_bar = False


class _Timer:
    """Lightning callback: wall time between consecutive batch starts (the whole iteration)."""

    def __init__(self) -> None:
        self.starts: list[float] = []

    def times(self) -> list[float]:
        return [b - a for a, b in zip(self.starts, self.starts[1:], strict=False)]


def time_lightning(
    module: AdversarialSegmentation,
    batch: dict,
    iters: int,
    precision: str = "32-true",
    losses: list[dict[str, float]] | None = None,
) -> list[float]:
    """Seconds per iteration under a Trainer that logs as ``uss-train`` does (TensorBoard
    into a temporary folder, ``log_every_n_steps: 10`` of ``configs/trainer/default.yaml``),
    at ``precision`` (``trainer.precision``). ``losses`` receives each iteration's ``train/*``
    scalars (a host sync per iteration: pass it only when not timing)."""
    from lightning.pytorch import Callback, Trainer
    from lightning.pytorch.loggers import TensorBoardLogger

    timer = _Timer()

    class Hook(Callback):
        def on_train_batch_start(self, *args: object) -> None:
            timer.starts.append(clock())

        def on_train_batch_end(self, trainer: object, pl_module: object, *args: object) -> None:
            if losses is not None:  # before the module's own hook clears its step values
                step: StepValues = pl_module._step_values[0]  # type: ignore[attr-defined]
                scalars = pl_module.method.train_scalars(step)  # type: ignore[attr-defined]
                losses.append({k: float(v) for k, v in scalars.items()})

        def on_train_end(self, *args: object) -> None:
            timer.starts.append(clock())

    loader = torch.utils.data.DataLoader(_Repeat(batch, iters), batch_size=None)
    with tempfile.TemporaryDirectory(prefix="train_step_") as logdir:
        trainer = Trainer(
            accelerator="cpu",
            max_epochs=1,
            precision=precision,
            logger=TensorBoardLogger(logdir, name="", version=""),
            log_every_n_steps=10,
            enable_checkpointing=False,
            enable_progress_bar=progress_bar,
            enable_model_summary=False,
            callbacks=[Hook()],
        )
        trainer.fit(module, train_dataloaders=loader)
    return timer.times()


def time_plain(state: PlainState, batch: dict, iters: int, weights: LossWeights) -> list[float]:
    times = []
    for _ in range(iters):
        start = clock()
        plain_iteration(state, batch, weights)
        times.append(clock() - start)
    return times


def max_difference(a: nn.Module, b: nn.Module) -> float:
    sa, sb = a.state_dict(), b.state_dict()
    return max(float((sa[k].float() - sb[k].float()).abs().max()) for k in sa)


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
    freeze_bn: bool = True

    def start(self) -> tuple[AdversarialSegmentation, dict]:
        """The seeded module and fixed random batch every variant starts from (BatchNorm
        statistics calibrated on the batch)."""
        torch.manual_seed(0)
        module = build_module(self.backbone, ndf=self.ndf, freeze_bn=self.freeze_bn)
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
    the small network at 33x33 and batch 1, the ResNets the paper's."""
    freeze_bn = not args.train_bn
    out = []
    for name in args.models:
        if name == "small":
            out.append(Case("resnet_small", 129, 4, args.iters * 4, args.repeats, 16, freeze_bn))
        elif name == "tiny":
            out.append(Case("resnet_small", 33, 1, args.iters * 20, args.repeats, 16, freeze_bn))
        else:
            out.append(Case(name, 321, 1, args.iters, args.repeats, 64, freeze_bn))
    return out


def run(case: Case, compare: type[AdversarialSegmentation] | None = None) -> None:
    module, batch = case.start()
    weights = module.loss_weights
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
            results[name] += time_lightning(variant, batch, case.iters)[1:]
    # Same computation: from the same start, module and plain loop end with the same weights.
    check_module = copy.deepcopy(module)
    check_module.batch_domains = False
    check_state = plain_state_from(check_module)
    time_lightning(check_module, batch, 2)
    for _ in range(2):
        plain_iteration(check_state, batch, weights)
    diff = max_difference(check_module.segmenter, check_state.segmenter)
    if not all(torch.isfinite(p).all() for p in check_state.segmenter.parameters()):
        raise SystemExit(f"{case.backbone}: the plain loop produced non-finite weights")
    plain = statistics.median(results["plain"])
    base = statistics.median(results["lightning"])
    bn = "frozen BN" if case.freeze_bn else "BN trained (batched variants run unbatched)"
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


@dataclass(frozen=True)
class Speed:
    """One variant of ``--suite speed``: module attributes and the trainer's precision."""

    settings: dict[str, object] = field(default_factory=dict)
    precision: str = "32-true"


FAST_CPU = Speed({"channels_last": True, "optimizer_kernels": "fused"}, "bf16-mixed")
"""What ``trainer=fast_cpu`` sets (a test keeps the two equal)."""

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
    weights = module.loss_weights
    speeds = {name: SPEED_VARIANTS[name] for name in variants or SPEED_VARIANTS}
    # One instance per variant for the whole run: compiled networks compile in its first fit.
    instances = {name: speed_variant(module, speed) for name, speed in speeds.items()}
    first: dict[str, float] = {}
    results: dict[str, list[float]] = {"plain": [], **{name: [] for name in speeds}}
    names = list(results)
    state = plain_state_from(module)
    for repeat in range(case.repeats):
        for name in names[repeat % len(names) :] + names[: repeat % len(names)]:
            if name == "plain":
                results["plain"] += time_plain(state, batch, case.iters, weights)[1:]
                continue
            times = time_lightning(instances[name], batch, case.iters, speeds[name].precision)
            first.setdefault(name, times[0])
            results[name] += times[1:]
    # Same computation: 2 iterations of every variant from the same start, against eager.
    losses: dict[str, list[dict[str, float]]] = {}
    finals: dict[str, dict[str, Tensor]] = {}
    for name, variant in instances.items():
        _restart(variant, module)
        losses[name] = []
        time_lightning(variant, batch, 2, speeds[name].precision, losses[name])
        finals[name] = {k: v.detach().float().clone() for k, v in variant.state_dict().items()}
    plain = statistics.median(results["plain"])
    eager = statistics.median(results["eager"]) if "eager" in results else plain
    bn = "frozen BN" if case.freeze_bn else "BN trained (domains unbatched)"
    print(
        f"{case.heading(bn)}: median s/iteration "
        f"over {case.iters - 1} x {case.repeats} iterations each (the first of each fit excluded)"
    )
    print(
        f"  {'variant':14s} {'s/it':>8s} {'vs plain':>9s} {'vs eager':>9s} {'compile s':>10s} "
        f"{'max |dloss|/loss':>17s} {'max |dweight|':>14s}"
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
        print(
            f"  {name:14s} {median:8.4f} {median / plain:9.3f} {median / eager:9.3f} "
            f"{'-' if compile_s is None else f'{compile_s:.1f}':>10s} {loss_diff:>17s} "
            f"{weight_diff:>14s}"
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
        help="BatchNorm in train mode (the demo experiment) instead of frozen (the paper)",
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
        print(
            f"torch {torch.__version__}, {args.threads} threads, {args.clock} clock, "
            f"{'warm' if args.warm_cache else 'cold'} compile cache, load "
            f"{os.getloadavg()[0]:.1f}"
        )
        for case in cases(args):
            run_speed(case, args.variants)
        print(f"load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()

"""The plain-PyTorch reference of one training iteration (the paper's Algorithm 1), written out
independently of the Lightning module, and the builders of the module it is compared with.

The step tests train :class:`~uss_slam.train.module.AdversarialSegmentation` and this loop from the
same start on the same batch and compare weights and losses; ``benchmarks/train_step.py`` times the
two against each other.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from uss_slam.models import DeepLabV2, PatchDiscriminator
from uss_slam.train.methods import AdaptSegNet
from uss_slam.train.module import AdversarialSegmentation
from uss_slam.train.schedules import PolyLR


@dataclass
class PlainState:
    """Everything a plain training loop owns."""

    segmenter: DeepLabV2
    d_aux: nn.Module | None
    d_main: nn.Module | None
    opt_seg: torch.optim.Optimizer
    opt_d: torch.optim.Optimizer | None
    sched_seg: PolyLR
    sched_d: PolyLR | None


def _up(logits: Tensor, size: torch.Size) -> Tensor:
    return F.interpolate(logits, size=size, mode="bilinear", align_corners=True)


def _bce(logits: Tensor, label: float) -> Tensor:
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, label))


def source_loss(
    segmenter: nn.Module, batch: dict, weights: PaperWeights, out_src: Any = None
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
    weights: PaperWeights,
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


@dataclass(frozen=True)
class PaperWeights:
    """The four λ of Algorithm 1 (paper §3.3 defaults), as the plain loop reads them."""

    lambda_seg_aux: float = 0.1
    lambda_seg_main: float = 1.0
    lambda_adv_aux: float = 0.002
    lambda_adv_main: float = 0.01


def weights_of(module: AdversarialSegmentation) -> PaperWeights:
    """The module's source-loss weights and its method's adversarial ones."""
    seg = module.loss_weights
    method = module.method
    return PaperWeights(
        seg.lambda_seg_aux,
        seg.lambda_seg_main,
        getattr(method, "lambda_adv_aux", 0.0),
        getattr(method, "lambda_adv_main", 0.0),
    )


def _params(*modules: nn.Module | None) -> Iterator[nn.Parameter]:
    for module in modules:
        if module is not None:
            yield from module.parameters()


def plain_state_from(module: AdversarialSegmentation) -> PlainState:
    """Deep copies of the module's networks with freshly built optimisers and schedules."""
    seg = copy.deepcopy(module.segmenter)
    lr = module.optimizer_factory.keywords["lr"]
    opt_seg = module.optimizer_factory(params=seg.param_groups(lr, module.head_lr_mult))
    sched_seg = PolyLR(opt_seg, module.poly_total_iters, module.poly_power)
    if module.method.discriminators is None:  # a method without discriminators
        return PlainState(seg, None, None, opt_seg, None, sched_seg, None)
    d_aux, d_main = copy.deepcopy(module.method.d_aux), copy.deepcopy(module.method.d_main)
    opt_d = module.method.d_optimizer_factory(
        params=list(d_aux.parameters()) + list(d_main.parameters())
    )
    return PlainState(
        seg,
        d_aux,
        d_main,
        opt_seg,
        opt_d,
        sched_seg,
        PolyLR(opt_d, module.poly_total_iters, module.poly_power),
    )


def build_module(
    backbone: str, max_iters: int = 1000, n_layers: int = 5, ndf: int = 64, freeze_bn: bool = True
) -> AdversarialSegmentation:
    """The module with the paper's optimisers (SGD 2.5e-4 Nesterov, Adam 1e-4) on a 4-class
    DeepLab-v2 of ``backbone`` and discriminators of ``n_layers`` layers and width ``ndf``."""
    net = DeepLabV2(num_classes=4, backbone=backbone, freeze_bn=freeze_bn)
    return AdversarialSegmentation(
        net=net,
        optimizer=functools.partial(
            torch.optim.SGD, lr=2.5e-4, momentum=0.9, nesterov=True, weight_decay=1e-4
        ),
        method=AdaptSegNet(
            discriminator=functools.partial(PatchDiscriminator, 4, n_layers, ndf),
            d_optimizer=functools.partial(torch.optim.Adam, lr=1e-4, betas=(0.9, 0.99)),
        ),
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
    """A seeded ``{"source": {"image", "label"}, "target": {"image"}}`` batch of ``batch``
    random ``size`` x ``size`` images; the labels' first 4 rows are ignore (255)."""
    g = torch.Generator().manual_seed(seed)
    label = torch.randint(0, 4, (batch, size, size), generator=g)
    label[:, :4] = 255
    return {
        "source": {"image": torch.randn(batch, 3, size, size, generator=g), "label": label},
        "target": {"image": torch.randn(batch, 3, size, size, generator=g)},
    }


def max_difference(a: nn.Module, b: nn.Module) -> float:
    """The largest absolute difference between two networks' state (weights and buffers)."""
    sa, sb = a.state_dict(), b.state_dict()
    return max(float((sa[k].float() - sb[k].float()).abs().max()) for k in sa)

"""studies/d_probe.py: the softmax maps of each BatchNorm mode are those the training step
computes in that mode, and an offline discriminator separates maps that differ."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import torch
from torch import nn

from uss_slam.testing.scripts import load_script

d_probe = load_script(Path(__file__).resolve().parents[2] / "studies" / "d_probe.py")
fit, maps = d_probe.fit, d_probe.maps


class Tiny(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 4, 3, padding=1)
        self.bn = nn.BatchNorm2d(4)

    def forward(self, x: torch.Tensor) -> SimpleNamespace:
        return SimpleNamespace(main=self.bn(self.conv(x)))


def _net() -> Tiny:
    torch.manual_seed(0)
    net = Tiny()
    net.bn.running_mean.fill_(0.3)
    net.bn.running_var.fill_(2.0)
    return net


def test_each_mode_normalises_like_the_training_step() -> None:
    net = _net()
    g = torch.Generator().manual_seed(1)
    src = torch.rand(4, 3, 8, 8, generator=g)
    trg = torch.rand(4, 3, 8, 8, generator=g) * 3 + 1  # another brightness: other statistics

    def soft(x: torch.Tensor, train: bool) -> torch.Tensor:
        n = _net().train(train)
        return torch.softmax(n(x).main, 1)

    with torch.no_grad():
        own_s, own_t = soft(src, True), soft(trg, True)
        run_s, run_t = soft(src, False), soft(trg, False)
        both = torch.softmax(_net().train()(torch.cat([src, trg])).main, 1)
    for mode, want_s, want_t in [
        ("separate", own_s, own_t),
        ("joint", both[:4], both[4:]),
        ("running", own_s, run_t),
        ("eval", run_s, run_t),
    ]:
        ms, mt = maps(net, src, trg, mode)
        torch.testing.assert_close(ms, want_s, msg=mode)
        torch.testing.assert_close(mt, want_t, msg=mode)
    # the checkpoint's network and running statistics are left as they were
    assert torch.all(net.bn.running_mean == 0.3) and torch.all(net.bn.running_var == 2.0)
    # separate makes the target maps look like the source's; running keeps their domain
    sep = maps(net, src, trg, "separate")
    run = maps(net, src, trg, "running")
    gap = lambda m: (m[0].mean((0, 2, 3)) - m[1].mean((0, 2, 3))).abs().sum()  # noqa: E731
    assert gap(sep) < gap(run)


def test_a_discriminator_separates_maps_that_differ_and_not_equal_ones() -> None:
    g = torch.Generator().manual_seed(2)
    a = torch.softmax(torch.randn(48, 4, 32, 32, generator=g), 1)
    b = torch.softmax(torch.randn(48, 4, 32, 32, generator=g) + torch.tensor([3.0, 0, 0, 0])[
        None, :, None, None], 1)  # fmt: skip
    far = fit(a[:32], b[:32], a[32:], b[32:], ndf=8, lr=1e-3, steps=60, seed=0)
    same = fit(a[:32], a[:32], a[32:], a[32:], ndf=8, lr=1e-3, steps=60, seed=0)
    assert far["held_out_acc"] > 0.9
    assert abs(same["held_out_acc"] - 0.5) < 0.1

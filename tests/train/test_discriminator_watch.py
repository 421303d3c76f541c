"""The discriminators' watch: block means of the domain accuracy and the chance rule."""

from __future__ import annotations

import pytest
import torch

from uss_slam.train.methods.adversarial import WATCH_BLOCK, DiscriminatorWatch
from uss_slam.train.methods.base import Method


def _step(right_src: float, right_trg: float) -> dict[str, torch.Tensor]:
    """Discriminator logits (N=1, 1, 2, 5: 10 patches) of which the given shares are right
    (source: logit < 0; target: logit > 0)."""

    def logits(right: float, sign: float) -> torch.Tensor:
        k = round(10 * right)
        values = torch.tensor([sign] * k + [-sign] * (10 - k))
        return values.reshape(1, 1, 2, 5)

    step = {}
    for head in ("aux", "main"):
        step[f"d_src_{head}"] = logits(right_src, -1.0)
        step[f"d_trg_{head}"] = logits(right_trg, 1.0)
        step[f"loss_d_src_{head}"] = torch.tensor(0.7)
        step[f"loss_d_trg_{head}"] = torch.tensor(0.7)
    return step


def test_block_means_and_a_discriminator_that_leaves_chance() -> None:
    watch = DiscriminatorWatch()
    for _ in range(WATCH_BLOCK):
        watch.add(_step(0.5, 0.5))  # chance: 0.5
    for _ in range(WATCH_BLOCK):
        watch.add(_step(1.0, 0.8))  # 0.9
    for _ in range(3):
        watch.add(_step(0.6, 0.6))  # a short last block: 0.6
    summary = watch.summary()
    assert watch.blocks["main"] == pytest.approx([0.5, 0.9, 0.6]) == watch.blocks["aux"]
    assert summary["train/d_acc_main_peak"] == pytest.approx(0.9)
    assert summary["train/d_acc_main_last"] == pytest.approx(0.6)
    assert summary["train/d_at_chance"] == 0.0


def test_every_block_in_the_band_is_chance() -> None:
    watch = DiscriminatorWatch()
    for i in range(2 * WATCH_BLOCK):
        watch.add(_step(0.4 if i % 2 else 0.6, 0.5))
    summary = watch.summary()
    assert summary["train/d_at_chance"] == 1.0
    assert summary["train/d_acc_aux_peak"] == pytest.approx(0.5, abs=0.01)


def test_no_iteration_no_figures() -> None:
    assert DiscriminatorWatch().summary() == {}


def test_methods_without_discriminators_report_nothing() -> None:
    assert Method.summary.__doc__ and "none by default" in Method.summary.__doc__
    from uss_slam.train.methods.source_only import SourceOnly

    assert SourceOnly().summary() == {}

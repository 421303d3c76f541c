"""train/losses.py: the segmentation loss is nll_loss's mean, and 0 on fully ignored labels."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from uss_slam.core.classes import IGNORE_INDEX
from uss_slam.train.losses import segmentation_loss


def test_segmentation_loss_equals_nll_mean_bit_for_bit() -> None:
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(3, 4, 17, 17, generator=g, requires_grad=True)
    labels = torch.randint(0, 4, (3, 17, 17), generator=g)
    labels[:, :5] = IGNORE_INDEX
    mine = segmentation_loss(F.log_softmax(logits, 1), labels)
    (grad_mine,) = torch.autograd.grad(mine, logits)
    ref = F.nll_loss(F.log_softmax(logits, 1), labels, ignore_index=IGNORE_INDEX)
    (grad_ref,) = torch.autograd.grad(ref, logits)
    assert torch.equal(mine, ref)
    assert torch.equal(grad_mine, grad_ref)


def test_segmentation_loss_is_zero_when_every_pixel_is_ignored() -> None:
    logits = torch.randn(2, 4, 9, 9, requires_grad=True)
    labels = torch.full((2, 9, 9), IGNORE_INDEX)
    loss = segmentation_loss(F.log_softmax(logits, 1), labels)
    assert loss.item() == 0.0  # nll_loss's own mean would be NaN (0 / 0)
    loss.backward()
    assert torch.equal(logits.grad, torch.zeros_like(logits))

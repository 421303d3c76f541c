"""model/method=minent: ADVENT's ``train_minent`` iteration against a plain PyTorch loop written
out here (the source loss: ``uss_slam.testing.reference_step``'s); no discriminator step; bad
weights are one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from hydra.utils import instantiate
from shared_helpers import compose_train
from torch import Tensor
from train_helpers import fit_repeated

from uss_slam.core.errors import UssSlamError
from uss_slam.models import DeepLabV2
from uss_slam.testing import reference_step as bench
from uss_slam.train.losses import LossWeights, entropy_loss
from uss_slam.train.methods import MinEnt


def _up(logits: Tensor, size: torch.Size) -> Tensor:
    return F.interpolate(logits, size=size, mode="bilinear", align_corners=True)


def advent_entropy_loss(v: Tensor) -> Tensor:
    """ADVENT's ``entropy_loss`` of softmax probabilities, as its code writes it."""
    n, c, h, w = v.size()
    return -torch.sum(torch.mul(v, torch.log2(v + 1e-30))) / (n * h * w * np.log2(c))


def plain_minent_iteration(state, batch: dict, w: LossWeights, ent_aux: float, ent_main: float):  # noqa: ANN001, ANN201
    seg = state.segmenter
    trg_img = batch["target"]["image"]
    state.opt_seg.zero_grad()
    bench.source_loss(seg, batch, w)[0].backward()
    out = seg(trg_img)
    p_aux = F.softmax(_up(out.aux, trg_img.shape[-2:]), dim=1)
    p_main = F.softmax(_up(out.main, trg_img.shape[-2:]), dim=1)
    (ent_aux * advent_entropy_loss(p_aux) + ent_main * advent_entropy_loss(p_main)).backward()
    state.opt_seg.step()
    state.sched_seg.step()


def test_entropy_loss_is_advents() -> None:
    logits = torch.randn(2, 4, 6, 5) * 2
    size = (11, 9)
    expected = advent_entropy_loss(F.softmax(_up(logits, size), dim=1))
    torch.testing.assert_close(entropy_loss(logits, size), expected)
    assert float(entropy_loss(torch.zeros(1, 4, 3, 3), (3, 3))) == pytest.approx(1.0)


@pytest.mark.parametrize("batch_domains", [True, False])
def test_minent_matches_plain_pytorch_reference(batch_domains: bool) -> None:
    torch.manual_seed(0)
    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8)
    # Weights large enough that the entropy term moves the weights beyond the tolerance.
    module.method = MinEnt(lambda_ent_aux=0.02, lambda_ent_main=0.1)
    module.batch_domains = batch_domains
    state = bench.plain_state_from(module)
    source_only = bench.plain_state_from(module)
    batch = bench.random_batch(41, 2)
    trainer = fit_repeated(module, batch, 3)
    for _ in range(3):
        plain_minent_iteration(state, batch, module.loss_weights, 0.02, 0.1)
    for key, value in module.segmenter.state_dict().items():
        torch.testing.assert_close(value, state.segmenter.state_dict()[key], rtol=0, atol=1e-6)
    # No discriminator: none built, one optimiser and its schedule.
    assert module.method.discriminators is None and len(trainer.optimizers) == 1
    assert module.lr_schedulers().last_epoch == 3
    # Without the entropy term the same loop ends elsewhere (the term is not a no-op).
    for _ in range(3):
        plain_minent_iteration(source_only, batch, module.loss_weights, 0.0, 0.0)
    diff = source_only.segmenter.main.branches[0].weight - module.segmenter.main.branches[0].weight
    assert float(diff.abs().max()) > 1e-5  # 10x the tolerance above


def test_minent_config_and_checks(tmp_path: Path) -> None:
    cfg = compose_train(["experiment=ci", "model/method=minent"], tmp_path / "r")
    model = instantiate(cfg.model)
    assert isinstance(model.method, MinEnt)
    assert (model.method.lambda_ent_aux, model.method.lambda_ent_main) == DEFAULT_WEIGHTS
    assert (MinEnt().lambda_ent_aux, MinEnt().lambda_ent_main) == DEFAULT_WEIGHTS
    assert model.hparams["method"] == "minent" and model.adaptation is True
    # No discriminators: the segmenter is all the module trains.
    assert {k.split(".")[0] for k in model.state_dict()} == {"segmenter"}
    with pytest.raises(UssSlamError, match="model.method.lambda_ent_main: expected a number >= 0"):
        MinEnt(lambda_ent_main=-1.0)
    with pytest.raises(UssSlamError, match="lambda_ent_aux"):
        MinEnt(lambda_ent_aux=True)  # type: ignore[arg-type]


ADVENT_WEIGHTS = (0.0002, 0.001)  # ADVENT's LAMBDA_ENT_AUX / LAMBDA_ENT_MAIN
DEFAULT_WEIGHTS = (0.01, 0.05)  # 50x ADVENT's, same aux : main ratio


def _gradient_ratio(weights: tuple[float, float]) -> float:
    """‖∇ weighted target entropy‖ / ‖∇ weighted source segmentation loss‖ over the segmenter's
    parameters, for a small DeepLab-v2 whose heads give confident-looking (not uniform) maps."""
    torch.manual_seed(0)
    net = DeepLabV2(4, "resnet_small", freeze_bn=False).train()
    with torch.no_grad():  # a trained net is far from its near-uniform initial softmax
        for head in (net.aux, net.main):
            for conv in head.branches:
                conv.weight.mul_(30.0)
    batch = bench.random_batch(33, 2)
    params = [p for p in net.parameters() if p.requires_grad]
    w = LossWeights()
    out = net(batch["source"]["image"])
    size = batch["source"]["label"].shape[-2:]
    ce = [
        F.nll_loss(F.log_softmax(_up(head, size), 1), batch["source"]["label"], ignore_index=255)
        for head in out
    ]
    seg = w.lambda_seg_aux * ce[0] + w.lambda_seg_main * ce[1]
    trg = net(batch["target"]["image"])
    ent = weights[0] * entropy_loss(trg.aux, size) + weights[1] * entropy_loss(trg.main, size)

    def norm(loss: Tensor) -> float:
        grads = torch.autograd.grad(loss, params, allow_unused=True)
        return float(torch.sqrt(sum((g**2).sum() for g in grads if g is not None)))

    return norm(ent) / norm(seg)


def test_the_default_entropy_weight_is_not_negligible() -> None:
    """At ADVENT's weights the entropy gradient is a rounding error next to the segmentation
    gradient (here 0.007%; in the demo 0.04-0.11% once trained); the default is 50x stronger."""
    advent, default = _gradient_ratio(ADVENT_WEIGHTS), _gradient_ratio(DEFAULT_WEIGHTS)
    assert default == pytest.approx(50 * advent, rel=1e-6)  # linear in the weights
    assert advent < 2e-4 and 2e-3 < default < 0.1

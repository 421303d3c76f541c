"""model/method=advent: ADVENT's iteration (valeoai/ADVENT ``train_advent``) against a plain
PyTorch loop written out here (the source loss: ``uss_slam.testing.reference_step``'s), its loss
weights from the config, and the depth sweep."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from hydra.utils import instantiate
from lightning.pytorch import Callback, LightningModule, Trainer
from shared_helpers import compose_train
from torch import Tensor
from train_helpers import ADVERSARIAL_SCALARS, assert_weights_match_reference, fit_repeated

from uss_slam.testing import reference_step as bench
from uss_slam.train.losses import LossWeights, self_information
from uss_slam.train.methods import AdvEnt
from uss_slam.train.methods import advent as advent_module

ADVENT_WEIGHTS = bench.PaperWeights(lambda_adv_aux=0.0002, lambda_adv_main=0.001)


def _up(logits: Tensor, size: torch.Size) -> Tensor:
    return F.interpolate(logits, size=size, mode="bilinear", align_corners=True)


def _bce(logits: Tensor, label: float) -> Tensor:
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, label))


def prob_2_entropy(prob: Tensor) -> Tensor:
    """ADVENT's ``prob_2_entropy`` as its code writes it."""
    c = prob.shape[1]
    return -torch.mul(prob, torch.log2(prob + 1e-30)) / np.log2(c)


def plain_advent_iteration(state, batch: dict, w: bench.PaperWeights) -> None:  # noqa: ANN001
    """One ADVENT iteration written out (the discriminator losses not halved, as this
    project's shared discriminator step)."""
    seg, d_aux, d_main = state.segmenter, state.d_aux, state.d_main
    trg_img = batch["target"]["image"]
    for p in [*d_aux.parameters(), *d_main.parameters()]:
        p.requires_grad_(False)
    state.opt_seg.zero_grad()
    loss_seg, src_aux, src_main = bench.source_loss(seg, batch, w)  # AdaptSegNet's step (1)
    loss_seg.backward()
    out = seg(trg_img)
    trg_aux, trg_main = _up(out.aux, trg_img.shape[-2:]), _up(out.main, trg_img.shape[-2:])
    loss_adv = w.lambda_adv_aux * _bce(d_aux(prob_2_entropy(F.softmax(trg_aux, 1))), 0.0)
    loss_adv = loss_adv + w.lambda_adv_main * _bce(
        d_main(prob_2_entropy(F.softmax(trg_main, 1))), 0.0
    )
    loss_adv.backward()
    state.opt_seg.step()
    for p in [*d_aux.parameters(), *d_main.parameters()]:
        p.requires_grad_(True)
    state.opt_d.zero_grad()
    maps = [prob_2_entropy(F.softmax(x.detach(), 1)) for x in (src_aux, src_main)]
    (_bce(d_aux(maps[0]), 0.0) + _bce(d_main(maps[1]), 0.0)).backward()
    maps = [prob_2_entropy(F.softmax(x.detach(), 1)) for x in (trg_aux, trg_main)]
    (_bce(d_aux(maps[0]), 1.0) + _bce(d_main(maps[1]), 1.0)).backward()
    state.opt_d.step()
    state.sched_d.step()
    state.sched_seg.step()


def _module(batch_domains: bool):  # noqa: ANN202
    torch.manual_seed(0)
    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8)
    adaptsegnet = module.method
    module.method = AdvEnt(
        discriminator=lambda: None,
        d_optimizer=adaptsegnet.d_optimizer_factory,
        lambda_adv_aux=ADVENT_WEIGHTS.lambda_adv_aux,
        lambda_adv_main=ADVENT_WEIGHTS.lambda_adv_main,
    )
    module.method.d_aux, module.method.d_main = adaptsegnet.d_aux, adaptsegnet.d_main
    module.batch_domains = batch_domains
    return module


def test_self_information_is_advents_map() -> None:
    logits = torch.randn(2, 4, 5, 7) * 3
    info = self_information(F.log_softmax(logits, dim=1))
    torch.testing.assert_close(info, prob_2_entropy(F.softmax(logits, dim=1)))
    # Summed over classes: the normalised entropy, 1 for a uniform prediction, 0 for a certain one.
    uniform = self_information(F.log_softmax(torch.zeros(1, 4, 2, 2), dim=1)).sum(dim=1)
    torch.testing.assert_close(uniform, torch.ones(1, 2, 2))
    certain = torch.full((1, 4, 1, 1), -1e4)
    certain[:, 2] = 1e4
    assert float(self_information(F.log_softmax(certain, dim=1)).sum()) == 0.0
    assert float(info.max()) <= 1 / (math.e * math.log(4)) + 1e-7


@pytest.mark.parametrize("batch_domains", [True, False])
def test_advent_matches_plain_pytorch_reference(batch_domains: bool) -> None:
    module = _module(batch_domains)
    state = bench.plain_state_from(module)
    batch = bench.random_batch(41, 2)
    fit_repeated(module, batch, 3)
    for _ in range(3):
        plain_advent_iteration(state, batch, ADVENT_WEIGHTS)
    # Last-bit differences (batched convolutions, log-softmax vs softmax + log2), magnified by
    # Adam in the discriminators.
    assert_weights_match_reference(module, state)
    assert module.iteration == 3
    # The discriminators saw self-information maps: an AdaptSegNet loop ends elsewhere.
    other = bench.plain_state_from(_module(batch_domains))
    for _ in range(3):
        bench.plain_iteration(other, batch, ADVENT_WEIGHTS)
    assert not torch.allclose(other.d_main.layers[0].weight, module.method.d_main.layers[0].weight)


def test_advent_config_sets_advents_weights_and_keeps_the_depth_sweep(tmp_path: Path) -> None:
    cfg = compose_train(
        ["experiment=ci", "model/method=advent", "model.method.discriminator.n_layers=6"],
        tmp_path / "r",
    )
    model = instantiate(cfg.model)
    assert isinstance(model.method, AdvEnt) and model.hparams["method"] == "advent"
    assert model.loss_weights == LossWeights(0.1, 1.0)
    assert (model.method.lambda_adv_aux, model.method.lambda_adv_main) == (0.0002, 0.001)
    assert model.method.d_main.n_layers == 6 and model.method.d_aux.n_layers == 6
    # An explicit weight wins over the method's default; other methods keep the paper's.
    cfg = compose_train(
        ["experiment=ci", "model/method=advent", "model.method.lambda_adv_main=0.005"],
        tmp_path / "r",
    )
    assert cfg.model.method.lambda_adv_main == 0.005 and cfg.model.method.lambda_adv_aux == 0.0002
    cfg = compose_train(["experiment=ci"], tmp_path / "r")
    assert (cfg.model.method.lambda_adv_aux, cfg.model.method.lambda_adv_main) == (0.002, 0.01)


class _Scalars(Callback):
    def __init__(self) -> None:
        self.keys: list[set[str]] = []

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, *_: object) -> None:
        step, _n = pl_module._step_values
        self.keys.append(set(pl_module._train_scalars(step)))


def test_advent_logs_adaptsegnets_keys_and_trains_the_discriminators() -> None:
    module = _module(True)
    d_before = copy.deepcopy(module.method.d_main.state_dict())
    probe = _Scalars()
    fit_repeated(module, bench.random_batch(41, 1), 1, [probe])
    assert not all(
        torch.equal(v, d_before[k]) for k, v in module.method.d_main.state_dict().items()
    )
    assert probe.keys == [ADVERSARIAL_SCALARS]
    sched_seg, sched_d = module.lr_schedulers()
    assert (sched_seg.last_epoch, sched_d.last_epoch) == (1, 1)


# AdaptSegNet's multi-level code (train_gta2cityscapes_multi.py): LAMBDA_ADV_TARGET1 (aux) and
# LAMBDA_ADV_TARGET2 (main).
ADAPTSEGNET_MULTI_LEVEL = (0.0002, 0.001)
CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def test_advent_weights_are_documented_as_adaptsegnets(tmp_path: Path) -> None:
    """ADVENT's adversarial weights equal AdaptSegNet's multi-level ones; the project's
    adaptsegnet defaults (the USS-SLAM paper's) are ten times both."""
    advent = instantiate(compose_train(["experiment=ci", "model/method=advent"], tmp_path).model)
    paper = instantiate(compose_train(["experiment=ci"], tmp_path).model)
    advent_weights = (advent.method.lambda_adv_aux, advent.method.lambda_adv_main)
    paper_weights = (paper.method.lambda_adv_aux, paper.method.lambda_adv_main)
    assert advent_weights == ADAPTSEGNET_MULTI_LEVEL
    assert paper_weights == pytest.approx(tuple(10 * w for w in ADAPTSEGNET_MULTI_LEVEL))
    doc = " ".join((advent_module.__doc__ or "").split())
    assert "equal to AdaptSegNet's multi-level ones" in doc and "ten times both" in doc
    assert "below AdaptSegNet" not in doc
    yaml = " ".join((CONFIGS / "model/method/advent.yaml").read_text().split())
    assert "below AdaptSegNet" not in yaml and "equal to # AdaptSegNet's multi-level" in yaml

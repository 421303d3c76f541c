"""The poly learning-rate schedules as the optimisers apply them, against the closed form
``lr_i = base × (1 - i / horizon) ** 0.9`` written out here (independent of
``uss_slam.train.schedules``): SGD's backbone and heads groups (heads at 10×) and Adam's
discriminator group, at every iteration of a short run. By default the horizon lies at
``max_iters × 250/150`` (the reference code's 250k-iteration schedule stopped at 150k)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from hydra.utils import instantiate
from lightning.pytorch import Callback, LightningModule, Trainer
from shared_helpers import compose_train
from train_helpers import fit_repeated

from uss_slam.testing import reference_step as bench

MAX_ITERS = 6


class AppliedRates(Callback):
    """``(iteration, optimiser index, [lr of each group])`` at every optimiser step."""

    def __init__(self) -> None:
        self.steps: list[tuple[int, int, list[float]]] = []

    def on_before_optimizer_step(
        self, trainer: Trainer, pl_module: LightningModule, optimizer: Any
    ) -> None:
        rates = [group["lr"] for group in optimizer.param_groups]
        self.steps.append((pl_module.iteration, trainer.optimizers.index(optimizer), rates))


def _closed_form(base: float, iteration: int, horizon: int) -> float:
    return base * (1.0 - iteration / horizon) ** 0.9


@pytest.mark.parametrize(
    ("method", "overrides", "horizon"),
    [
        ("adaptsegnet", [], 10),  # round(6 x 250 / 150)
        ("source_only", [], 10),
        ("adaptsegnet", [f"model.poly_total_iters={MAX_ITERS}"], MAX_ITERS),  # decays to 0
    ],
)
def test_poly_rates_follow_the_closed_form(
    method: str, overrides: list[str], horizon: int, tmp_path: Path
) -> None:
    cfg = compose_train(
        ["experiment=ci", f"model.max_iters={MAX_ITERS}", f"model/method={method}", *overrides],
        tmp_path,
    )
    torch.manual_seed(0)
    model = instantiate(cfg.model)
    assert model.poly_total_iters == model.hparams["poly_total_iters"] == horizon
    probe = AppliedRates()
    trainer = fit_repeated(model, bench.random_batch(33, 1), MAX_ITERS + 2, [probe])
    assert model.iteration == MAX_ITERS  # stops at max_iters, not at the end of the data

    # The paper's rates, written out: SGD 2.5e-4 (backbone), heads 10x; Adam 1e-4.
    adversarial = method == "adaptsegnet"
    assert len(trainer.optimizers) == (2 if adversarial else 1)  # no discriminators otherwise
    seg = trainer.optimizers[0]
    assert [g["name"] for g in seg.param_groups] == ["backbone", "heads"]
    expected = []
    for i in range(MAX_ITERS):
        expected.append(
            (i, 0, [_closed_form(2.5e-4, i, horizon), _closed_form(2.5e-3, i, horizon)])
        )
        if adversarial:
            expected.append((i, 1, [_closed_form(1.0e-4, i, horizon)]))
    assert [(i, k) for i, k, _ in probe.steps] == [(i, k) for i, k, _ in expected]
    for (i, k, rates), (_, _, want) in zip(probe.steps, expected, strict=True):
        assert rates == pytest.approx(want, rel=1e-12, abs=0), (i, k)
    # After the last iteration: 0 at a horizon of max_iters, else (1 - 150/250)^0.9 = 0.44x.
    end = _closed_form(1.0, MAX_ITERS, horizon)
    assert end == (0.0 if horizon == MAX_ITERS else pytest.approx(0.4**0.9))
    assert [g["lr"] for g in seg.param_groups] == pytest.approx([2.5e-4 * end, 2.5e-3 * end])
    if adversarial:
        assert trainer.optimizers[1].param_groups[0]["lr"] == pytest.approx(1.0e-4 * end)


def test_poly_horizon_before_the_end_is_refused(tmp_path: Path) -> None:
    cfg = compose_train(
        ["experiment=ci", "model.max_iters=6", "model.poly_total_iters=5"], tmp_path
    )
    with pytest.raises(Exception, match=r"model.poly_total_iters must be null or an integer >= "):
        instantiate(cfg.model)

"""The poly learning-rate schedules as the optimisers apply them, against the closed form
``lr_i = base × (1 - i / max_iters) ** 0.9`` written out here (independent of
``uss_slam.train.schedules``): SGD's backbone and heads groups (heads at 10×) and Adam's
discriminator group, at every iteration of a short run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
import train_step as bench
from hydra.utils import instantiate
from lightning.pytorch import Callback, LightningModule, Trainer
from shared_helpers import compose_train

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


def _closed_form(base: float, iteration: int) -> float:
    return base * (1.0 - iteration / MAX_ITERS) ** 0.9


@pytest.mark.parametrize("method", ["adaptsegnet", "source_only"])
def test_poly_rates_follow_the_closed_form(method: str, tmp_path: Path) -> None:
    cfg = compose_train(
        ["experiment=ci", f"model.max_iters={MAX_ITERS}", f"model/method={method}"], tmp_path
    )
    torch.manual_seed(0)
    model = instantiate(cfg.model)
    loader = torch.utils.data.DataLoader(
        bench._Repeat(bench.random_batch(33, 1), MAX_ITERS + 2), batch_size=None
    )
    probe = AppliedRates()
    trainer = Trainer(
        accelerator="cpu",
        max_epochs=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[probe],
    )
    trainer.fit(model, train_dataloaders=loader)
    assert model.iteration == MAX_ITERS  # stops at max_iters, not at the end of the data

    # The paper's rates, written out: SGD 2.5e-4 (backbone), heads 10x; Adam 1e-4.
    seg, disc = trainer.optimizers
    assert [g["name"] for g in seg.param_groups] == ["backbone", "heads"]
    assert len(disc.param_groups) == 1
    expected = []
    for i in range(MAX_ITERS):
        expected.append((i, 0, [_closed_form(2.5e-4, i), _closed_form(2.5e-3, i)]))
        if method == "adaptsegnet":
            expected.append((i, 1, [_closed_form(1.0e-4, i)]))
    assert [(i, k) for i, k, _ in probe.steps] == [(i, k) for i, k, _ in expected]
    for (i, k, rates), (_, _, want) in zip(probe.steps, expected, strict=True):
        assert rates == pytest.approx(want, rel=1e-12, abs=0), (i, k)
    # After the last iteration both schedules reach 0 (the discriminators' only if it stepped).
    assert [g["lr"] for g in seg.param_groups] == [0.0, 0.0]
    assert disc.param_groups[0]["lr"] == (0.0 if method == "adaptsegnet" else 1.0e-4)

"""Helpers of the training tests: callbacks that make a run diverge or score as scripted
(composing the config and the data overrides are in ``tests/shared_helpers.py``)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch import Callback, LightningModule, Trainer

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"


class PoisonAt(Callback):
    """Sets the segmenter's main-head bias to NaN before training iteration ``iteration``
    (a stand-in for a diverging run)."""

    def __init__(self, iteration: int) -> None:
        self.iteration = iteration

    def on_train_batch_start(
        self, trainer: Trainer, pl_module: LightningModule, batch: Any, batch_idx: int
    ) -> None:
        if pl_module.iteration == self.iteration:
            with torch.no_grad():
                pl_module.segmenter.main.branches[0].bias.fill_(float("nan"))


class ScriptedScore(Callback):
    """Logs ``val/score`` = ``scores[k]`` at the validation after epoch ``k`` of
    ``iterations_per_epoch`` iterations (a stand-in for a metric whose best epoch is known)."""

    def __init__(self, scores: Sequence[float], iterations_per_epoch: int) -> None:
        self.scores = list(scores)
        self.iterations_per_epoch = iterations_per_epoch

    def on_validation_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if trainer.sanity_checking:
            return
        epoch = pl_module.iteration // self.iterations_per_epoch - 1
        pl_module.log("val/score", self.scores[epoch])

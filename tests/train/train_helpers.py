"""Helpers of the training tests: data-path overrides, composing the real config, a callback
that makes a run diverge."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from lightning.pytorch import Callback, LightningModule, Trainer
from omegaconf import DictConfig, open_dict

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"


def data_overrides(data: dict[str, Path]) -> list[str]:
    return [
        f"data.source.root={data['voc']}",
        f"data.target.roots=[{data['target']}]",
        f"data.val.roots=[{data['val']}]",
        "data.val.stride=1",
    ]


def compose_train(overrides: Sequence[str], output_dir: Path) -> DictConfig:
    """The real ``train.yaml`` composed with ``overrides``; outputs go to ``output_dir``."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=list(overrides), return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(output_dir)
        cfg.hydra.job.num = 0
        cfg.paths.log_dir = str(output_dir.parent / "logs")
    HydraConfig().set_config(cfg)
    return cfg


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

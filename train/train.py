"""``uss-train``: compose the Hydra config, instantiate data / model / trainer, fit.

Examples::

    uss-train experiment=demo
    uss-train experiment=demo ckpt_path=last          # resume the newest demo run
    uss-train -m experiment=demo model.discriminator.n_layers=4,5,6,7

Returns the value of ``optimized_metric`` (``val/mIoU``) so Hydra sweepers can optimise it.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from hydra.utils import instantiate
from lightning.pytorch import Callback, LightningDataModule, LightningModule, Trainer
from lightning.pytorch.callbacks import LearningRateMonitor
from lightning.pytorch.loggers import Logger
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from uss_slam.core.cli import exit_on_user_error
from uss_slam.core.errors import UssSlamError

log = logging.getLogger(__name__)


def _instantiate_all(group: DictConfig | None) -> list[Any]:
    """Instantiate every entry with a ``_target_`` of a callbacks / logger group."""
    if not group:
        return []
    return [instantiate(node) for node in group.values() if node and "_target_" in node]


def resolve_ckpt_path(cfg: DictConfig) -> str | None:
    """``ckpt_path``: ``null`` (fresh run), a file, or ``last`` = the newest ``last.ckpt`` of
    an earlier run of the same ``run_name`` under ``paths.log_dir``."""
    value = cfg.get("ckpt_path")
    if value is None:
        return None
    if str(value) != "last":
        path = Path(str(value))
        if not path.is_file():
            raise UssSlamError(f"ckpt_path {path} does not exist")
        return str(path)
    runs = Path(cfg.paths.log_dir) / cfg.task_name / "runs" / str(cfg.run_name)
    output_dir = Path(cfg.paths.output_dir).resolve()
    candidates = [
        p for p in runs.glob("*/checkpoints/last.ckpt") if output_dir not in p.resolve().parents
    ]
    if not candidates:
        raise UssSlamError(
            f"ckpt_path=last: no checkpoints/last.ckpt in an earlier run under {runs}"
        )
    newest = max(candidates, key=lambda p: p.stat().st_mtime)
    log.info("resuming from %s", newest)
    return str(newest)


def train(cfg: DictConfig) -> dict[str, float]:
    """Fit the configured model; returns the final callback metrics as floats."""
    if cfg.get("num_threads"):
        torch.set_num_threads(int(cfg.num_threads))
    if cfg.get("seed") is not None:
        L.seed_everything(int(cfg.seed), workers=True, verbose=False)
    ckpt_path = resolve_ckpt_path(cfg)

    datamodule: LightningDataModule = instantiate(cfg.data)
    model: LightningModule = instantiate(cfg.model)
    callbacks: list[Callback] = _instantiate_all(cfg.get("callbacks"))
    loggers: list[Logger] = _instantiate_all(cfg.get("logger"))
    if not loggers:  # `logger=none`: nothing to monitor learning rates into
        callbacks = [c for c in callbacks if not isinstance(c, LearningRateMonitor)]
    trainer: Trainer = instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)

    hparams = OmegaConf.to_container(cfg, resolve=True)
    for logger in loggers:
        logger.log_hyperparams(hparams)  # type: ignore[arg-type]

    trainer.fit(model, datamodule=datamodule, ckpt_path=ckpt_path)

    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    checkpoint = getattr(trainer.checkpoint_callback, "best_model_path", "")
    if trainer.is_global_zero:
        log.info(
            "iterations: %s, best checkpoint: %s", getattr(model, "iteration", "?"), checkpoint
        )
        log.info("metrics: %s", {k: round(v, 4) for k, v in metrics.items()})
    return metrics


@hydra.main(version_base="1.3", config_path="../configs", config_name="train")
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns ``cfg.optimized_metric`` for sweepers."""
    with exit_on_user_error("uss-train", (OmegaConfBaseException,)):
        metrics = train(cfg)
    metric = cfg.get("optimized_metric")
    return metrics.get(metric) if metric else None


if __name__ == "__main__":
    main()

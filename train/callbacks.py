"""Training callbacks: TensorBoard prediction images and a DDP replica consistency check."""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.loggers import TensorBoardLogger

from uss_slam.datasets.classes import colorize
from uss_slam.datasets.errors import UssSlamError
from uss_slam.datasets.transforms import IMAGENET_MEAN, IMAGENET_STD, denormalize
from uss_slam.train.losses import upsample

log = logging.getLogger(__name__)


def prediction_panel(
    image: torch.Tensor,
    prediction: torch.Tensor,
    label: torch.Tensor | None,
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> np.ndarray:
    """``input | prediction | label`` side by side as ``(H, 2W or 3W, 3)`` uint8 RGB.

    ``image`` is one normalised ``(3, H, W)`` image, ``prediction`` and ``label`` ``(H, W)``
    class ids (label ``None``: two panels).
    """
    parts = [denormalize(image.detach().float().cpu(), mean, std).numpy()]
    parts.append(colorize(prediction.cpu().numpy().astype(np.uint8)))
    if label is not None:
        parts.append(colorize(label.cpu().numpy().astype(np.uint8)))
    return np.concatenate(parts, axis=1)


class SegmentationImageLogger(Callback):
    """Logs ``input | prediction | label`` panels (main head, coloured with
    ``classes.colorize``) to TensorBoard: source and target every ``every_n_iterations``
    training iterations, and the first validation batch of every validation run."""

    def __init__(
        self,
        every_n_iterations: int = 500,
        mean: Sequence[float] = IMAGENET_MEAN,
        std: Sequence[float] = IMAGENET_STD,
    ) -> None:
        if every_n_iterations <= 0:
            raise ValueError("every_n_iterations must be positive")
        self.every_n_iterations = every_n_iterations
        self.mean = tuple(mean)
        self.std = tuple(std)

    @staticmethod
    def _tensorboard(trainer: Trainer) -> Any | None:
        for logger in trainer.loggers:
            if isinstance(logger, TensorBoardLogger):
                return logger.experiment
        return None

    @torch.no_grad()
    def _panel(self, module: LightningModule, sample: dict[str, Any]) -> np.ndarray:
        images = sample["image"][:1]
        logits = upsample(module.segmenter(images).main, images.shape[-2:])
        label = sample["label"][0] if "label" in sample else None
        return prediction_panel(images[0], logits.argmax(1)[0], label, self.mean, self.std)

    def on_train_batch_end(
        self, trainer: Trainer, pl_module: LightningModule, outputs: Any, batch: Any, batch_idx: int
    ) -> None:
        iteration = getattr(pl_module, "iteration", trainer.global_step)
        if iteration % self.every_n_iterations != 0 or not trainer.is_global_zero:
            return
        experiment = self._tensorboard(trainer)
        if experiment is None:
            return
        for domain in ("source", "target"):
            panel = self._panel(pl_module, batch[domain])
            experiment.add_image(f"train/{domain}", panel, iteration, dataformats="HWC")

    def on_validation_batch_end(
        self,
        trainer: Trainer,
        pl_module: LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        if batch_idx != 0 or trainer.sanity_checking or not trainer.is_global_zero:
            return
        experiment = self._tensorboard(trainer)
        if experiment is not None:
            panel = self._panel(pl_module, batch)
            step = getattr(pl_module, "iteration", trainer.global_step)
            experiment.add_image("val/target", panel, step, dataformats="HWC")


def state_digest(module: torch.nn.Module) -> str:
    """SHA-256 of every parameter and buffer (names, shapes and exact bytes)."""
    digest = hashlib.sha256()
    for name, tensor in sorted(module.state_dict().items()):
        data = tensor.detach().cpu().contiguous()
        digest.update(name.encode())
        digest.update(str(tuple(data.shape)).encode())
        digest.update(data.view(torch.uint8).numpy().tobytes() if data.numel() else b"")
    return digest.hexdigest()


class ReplicaConsistencyCheck(Callback):
    """After multi-process training, checks that every rank holds bit-identical weights
    (segmenter and discriminators) and writes the per-rank digests to ``<dirpath>/replicas.json``.
    A mismatch (a broken DDP setup) raises. Does nothing in single-process runs."""

    def __init__(self, dirpath: str | Path | None = None) -> None:
        self.dirpath = Path(dirpath) if dirpath is not None else None

    def on_train_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if trainer.world_size <= 1:
            return
        local = state_digest(pl_module)
        raw = torch.tensor(list(bytes.fromhex(local)), dtype=torch.int64)
        gathered = trainer.strategy.all_gather(raw.to(pl_module.device)).cpu()
        digests = [bytes(row.tolist()).hex() for row in gathered.reshape(trainer.world_size, -1)]
        if trainer.is_global_zero:
            log.info("weights digest per rank: %s", digests)
            if self.dirpath is not None:
                self.dirpath.mkdir(parents=True, exist_ok=True)
                (self.dirpath / "replicas.json").write_text(
                    json.dumps(
                        {"iteration": getattr(pl_module, "iteration", None), "digests": digests}
                    )
                )
        if len(set(digests)) != 1:
            raise UssSlamError(f"DDP replicas diverged: weight digests per rank {digests}")

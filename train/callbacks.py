"""Training callbacks: TensorBoard prediction images, a DDP replica consistency check, a
ModelCheckpoint that keeps its best score across resumes, and a progress bar that writes whole
lines to a file or log."""

from __future__ import annotations

import hashlib
import json
import logging
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.callbacks import ModelCheckpoint, TQDMProgressBar
from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm
from lightning.pytorch.loggers import TensorBoardLogger

from uss_slam.core.classes import colorize
from uss_slam.core.errors import UssSlamError
from uss_slam.core.progress import LineProgress, is_terminal
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


def state_digest(tensors: dict[str, torch.Tensor]) -> str:
    """SHA-256 of named tensors (names, shapes and exact bytes)."""
    digest = hashlib.sha256()
    for name, tensor in sorted(tensors.items()):
        data = tensor.detach().cpu().contiguous()
        digest.update(name.encode())
        digest.update(str(tuple(data.shape)).encode())
        digest.update(data.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


class ReplicaConsistencyCheck(Callback):
    """After multi-process training, checks that every rank holds bit-identical parameters
    (segmenter and discriminators) and buffers, and writes the per-rank digests to
    ``<dirpath>/replicas.json``. Diverged parameters (a broken DDP setup) raise; diverged
    buffers only warn: BatchNorm statistics are per rank unless synchronised
    (``trainer.sync_batchnorm=true``, GPUs only) or frozen. Does nothing in single-process runs.
    """

    def __init__(self, dirpath: str | Path | None = None) -> None:
        self.dirpath = Path(dirpath) if dirpath is not None else None

    @staticmethod
    def _gather(trainer: Trainer, pl_module: LightningModule, digest: str) -> list[str]:
        raw = torch.tensor(list(bytes.fromhex(digest)), dtype=torch.int64, device=pl_module.device)
        gathered = trainer.strategy.all_gather(raw).cpu().reshape(trainer.world_size, -1)
        return [bytes(row.tolist()).hex() for row in gathered]

    def on_train_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if trainer.world_size <= 1:
            return
        params = self._gather(trainer, pl_module, state_digest(dict(pl_module.named_parameters())))
        buffers = self._gather(trainer, pl_module, state_digest(dict(pl_module.named_buffers())))
        if trainer.is_global_zero:
            log.info("digest per rank: parameters %s, buffers %s", params, buffers)
            if self.dirpath is not None:
                self.dirpath.mkdir(parents=True, exist_ok=True)
                record = {
                    "iteration": getattr(pl_module, "iteration", None),
                    "parameters": params,
                    "buffers": buffers,
                }
                (self.dirpath / "replicas.json").write_text(
                    json.dumps(record, indent=1) + "\n", encoding="utf-8"
                )
        if len(set(params)) != 1:
            raise UssSlamError(f"DDP replicas diverged: parameter digests per rank {params}")
        if len(set(buffers)) != 1 and trainer.is_global_zero:
            log.warning(
                "buffers (BatchNorm statistics) differ across ranks: freeze BatchNorm or set "
                "trainer.sync_batchnorm=true (GPUs); checkpoints hold rank 0's"
            )


class ResumableModelCheckpoint(ModelCheckpoint):
    """:class:`~lightning.pytorch.callbacks.ModelCheckpoint` whose best-so-far survives a
    resume into another folder.

    Every ``uss-train`` run writes into its own folder, also when it resumes an earlier run
    (``ckpt_path=last``). Lightning then restores only ``best_model_path`` from the checkpoint's
    callback state (its ``dirpath`` differs), so the resumed run would take its first score for
    the best. This restores the whole score tracking (``best_model_score``, ``best_k_models``,
    ``kth_*``) of the earlier run's checkpoint files that still exist: a later score replaces
    them only if it is better. The earlier run's files are never deleted (Lightning removes
    only files in its own ``dirpath``). The state key is ModelCheckpoint's, so checkpoints
    written with either class restore into both.
    """

    @property
    def state_key(self) -> str:
        key = super().state_key
        return key.replace(type(self).__qualname__, ModelCheckpoint.__qualname__, 1)

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        if state_dict.get("dirpath", self.dirpath) == self.dirpath or self.monitor is None:
            with warnings.catch_warnings():
                # "dirpath has changed ... won't be reloaded": true, and handled here.
                warnings.filterwarnings("ignore", message="The dirpath has changed")
                super().load_state_dict(state_dict)
            return
        kept = {
            path: score
            for path, score in (state_dict.get("best_k_models") or {}).items()
            if Path(path).is_file()
        }
        self.best_k_models = kept
        if not kept:
            log.warning(
                "%s: the best checkpoints of the resumed run are gone; tracking starts anew",
                self.monitor,
            )
            self.best_model_path, self.best_model_score = "", None
            return
        better, worse = (max, min) if self.mode == "max" else (min, max)
        self.best_model_path = better(kept, key=lambda p: float(kept[p]))
        self.best_model_score = kept[self.best_model_path]
        self.kth_best_model_path = worse(kept, key=lambda p: float(kept[p]))
        self.kth_value = kept[self.kth_best_model_path]


class LogProgressBar(TQDMProgressBar):
    """Lightning's TQDM bars in a terminal; written to a file or a CI log (stdout is not a TTY)
    the bars of :mod:`uss_slam.core.progress` instead, which write whole lines (the first state,
    at most one every :data:`~uss_slam.core.progress.LOG_INTERVAL` seconds, the last) instead of
    one redraw per batch. ``uss-train`` uses it whenever ``trainer.enable_progress_bar`` is on."""

    def _lines(self) -> bool:
        return not is_terminal(sys.stdout)

    def init_sanity_tqdm(self) -> Tqdm:
        if not self._lines():
            return super().init_sanity_tqdm()
        return _LogTqdm(desc=self.sanity_check_description, disable=self.is_disabled,
                        leave=False, file=sys.stdout, bar_format=self.BAR_FORMAT)  # fmt: skip

    def init_train_tqdm(self) -> Tqdm:
        if not self._lines():
            return super().init_train_tqdm()
        return _LogTqdm(desc=self.train_description, disable=self.is_disabled, leave=True,
                        file=sys.stdout, smoothing=0, bar_format=self.BAR_FORMAT)  # fmt: skip

    def init_validation_tqdm(self) -> Tqdm:
        if not self._lines():
            return super().init_validation_tqdm()
        # (as Lightning's: a validation inside training is not left behind)
        leave = self.trainer.state.fn == "validate"
        return _LogTqdm(desc=self.validation_description, disable=self.is_disabled,
                        leave=leave, file=sys.stdout, bar_format=self.BAR_FORMAT)  # fmt: skip


class _LogTqdm(LineProgress, Tqdm):
    """Lightning's bar (its number format) writing whole lines."""

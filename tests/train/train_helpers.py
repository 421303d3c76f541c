"""Helpers of the training tests: a quiet CPU trainer and a fit on one batch repeated, the
scalars an adversarial iteration logs, the comparison of trained weights with the plain-PyTorch
reference's, and callbacks that make a run diverge or score as scripted
(composing the config and the data overrides are in ``tests/shared_helpers.py``)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch import Callback, LightningModule, Trainer

from uss_slam.testing.step_timing import RepeatedBatch

RENDEZVOUS = ("MASTER_ADDR", "MASTER_PORT", "WORLD_SIZE", "RANK", "LOCAL_RANK", "NODE_RANK")
"""torch.distributed's variables: Lightning's DDP sets them in ``os.environ``, and a
``uss-train`` started with them set joins (or fails to start) that group."""

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"

# The train/* scalars of an iteration that trains the discriminators (AdaptSegNet, ADVENT).
ADVERSARIAL_SCALARS = frozenset(
    {
        "train/loss_seg_src_aux",
        "train/loss_seg_src_main",
        "train/loss_adv_trg_aux",
        "train/loss_adv_trg_main",
        "train/loss_d_aux",
        "train/loss_d_main",
        "train/d_acc_aux",
        "train/d_acc_main",
    }
)


def quiet_trainer(**options: Any) -> Trainer:
    """A CPU ``Trainer`` for one epoch that writes nothing: no logger, checkpoints, progress bar
    or model summary; ``options`` (any ``Trainer`` argument) override these."""
    defaults: dict[str, Any] = {
        "accelerator": "cpu",
        "max_epochs": 1,
        "logger": False,
        "enable_checkpointing": False,
        "enable_progress_bar": False,
        "enable_model_summary": False,
    }
    return Trainer(**{**defaults, **options})


def repeated_loader(batch: dict, iters: int) -> torch.utils.data.DataLoader:
    """``batch`` as a loader of ``iters`` batches an epoch (already batched)."""
    return torch.utils.data.DataLoader(RepeatedBatch(batch, iters), batch_size=None)


def fit_repeated(
    module: LightningModule,
    batch: dict,
    iters: int,
    callbacks: Iterable[Callback] = (),
    *,
    ckpt_path: str | Path | None = None,
    **options: Any,
) -> Trainer:
    """Fit ``module`` on ``batch`` repeated ``iters`` times an epoch under
    :func:`quiet_trainer` (``options`` go to it), resumed from ``ckpt_path`` if given; returns
    the trainer."""
    trainer = quiet_trainer(callbacks=list(callbacks), **options)
    trainer.fit(module, train_dataloaders=repeated_loader(batch, iters), ckpt_path=ckpt_path)
    return trainer


def assert_weights_match_reference(module: LightningModule, state: Any) -> None:
    """The segmenter and discriminators of ``module`` equal those of ``state`` (the plain
    PyTorch loop's, ``uss_slam.testing.reference_step.plain_state_from``) to the rounding of the
    module's kernels, which differ in the last bit (batched / NHWC convolutions, softmax as
    exp(log_softmax)). Adam divides by the root of tiny second moments and so magnifies last-bit
    gradient differences: 1e-6 for the SGD-trained segmenter, 2e-5 for the Adam-trained
    discriminators (their weights are ~1e-2)."""
    pairs = [(module.segmenter, state.segmenter, 1e-6)]
    if module.method.discriminators is not None:
        pairs += [
            (module.method.d_aux, state.d_aux, 2e-5),
            (module.method.d_main, state.d_main, 2e-5),
        ]
    for mine, ref, atol in pairs:
        for key, value in mine.state_dict().items():
            torch.testing.assert_close(value, ref.state_dict()[key], rtol=0, atol=atol)


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

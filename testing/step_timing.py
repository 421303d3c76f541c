"""Seconds per training iteration of the Lightning module under a Trainer that logs as
``uss-train`` does, and the module settings of the ``--suite speed`` variants that
``benchmarks/train_step.py`` times (:data:`FAST_CPU` is what ``trainer=fast_cpu`` sets)."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from uss_slam.train.methods import StepValues
from uss_slam.train.module import AdversarialSegmentation


@dataclass(frozen=True)
class Speed:
    """One variant of ``--suite speed``: module attributes and the trainer's precision."""

    settings: dict[str, object] = field(default_factory=dict)
    precision: str = "32-true"


FAST_CPU = Speed({"channels_last": True, "optimizer_kernels": "fused"}, "bf16-mixed")
"""What ``trainer=fast_cpu`` sets (a test keeps the two equal)."""


class RepeatedBatch(torch.utils.data.Dataset):
    """``batch`` (already batched) ``n`` times: a loader of it needs ``batch_size=None``."""

    def __init__(self, batch: dict, n: int) -> None:
        self.batch, self.n = batch, n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int) -> dict:
        return self.batch


class _Timer:
    """Times between consecutive batch starts (the whole iteration)."""

    def __init__(self) -> None:
        self.starts: list[float] = []

    def times(self) -> list[float]:
        return [b - a for a, b in zip(self.starts, self.starts[1:], strict=False)]


def time_lightning(
    module: AdversarialSegmentation,
    batch: dict,
    iters: int,
    precision: str = "32-true",
    losses: list[dict[str, float]] | None = None,
    clock: Callable[[], float] = time.perf_counter,
    progress_bar: bool = False,
) -> list[float]:
    """Seconds per iteration (by ``clock``: ``time.perf_counter`` or ``time.process_time``)
    under a Trainer that logs as ``uss-train`` does (TensorBoard into a temporary folder,
    ``log_every_n_steps: 10`` of ``configs/trainer/default.yaml``; ``progress_bar``: the TQDM
    bar of an interactive run), at ``precision`` (``trainer.precision``). ``losses`` receives
    each iteration's ``train/*`` scalars (a host sync per iteration: pass it only when not
    timing)."""
    from lightning.pytorch import Callback, Trainer
    from lightning.pytorch.loggers import TensorBoardLogger

    timer = _Timer()

    class Hook(Callback):
        def on_train_batch_start(self, *args: object) -> None:
            timer.starts.append(clock())

        def on_train_batch_end(self, trainer: object, pl_module: object, *args: object) -> None:
            if losses is not None:  # before the module's own hook clears its step values
                step: StepValues = pl_module._step_values[0]  # type: ignore[attr-defined]
                scalars = pl_module.method.train_scalars(step)  # type: ignore[attr-defined]
                losses.append({k: float(v) for k, v in scalars.items()})

        def on_train_end(self, *args: object) -> None:
            timer.starts.append(clock())

    loader = torch.utils.data.DataLoader(RepeatedBatch(batch, iters), batch_size=None)
    with tempfile.TemporaryDirectory(prefix="train_step_") as logdir:
        trainer = Trainer(
            accelerator="cpu",
            max_epochs=1,
            precision=precision,
            logger=TensorBoardLogger(logdir, name="", version=""),
            log_every_n_steps=10,
            enable_checkpointing=False,
            enable_progress_bar=progress_bar,
            enable_model_summary=False,
            callbacks=[Hook()],
        )
        trainer.fit(module, train_dataloaders=loader)
    return timer.times()

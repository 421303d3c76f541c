"""Lightning ``Trainer`` settings the training cannot honour, refused before the trainer is built
(nothing is written yet) with one line naming their key, and Lightning's own configuration
errors named the same way.

The training step optimises the segmenter and the discriminators itself (Lightning's manual
optimization: two networks, their own optimisers and schedules), so Lightning's automatic
gradient clipping and accumulation do not apply; Lightning would refuse them only once
``fit`` starts, with its traceback. A callback list that saves checkpoints beside
``trainer.enable_checkpointing=false`` is refused by Lightning the same way.
"""

from __future__ import annotations

import re
from typing import Any

from hydra.errors import InstantiationException
from hydra.utils import instantiate
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.pytorch import Trainer
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from omegaconf import DictConfig

from uss_slam.core.errors import UssSlamError

MANUAL = "the training step optimises its networks itself (Lightning's manual optimization)"

# Trainer key -> (its values that change nothing, the one to write, what Lightning would not do)
UNSUPPORTED: dict[str, tuple[tuple[Any, ...], str, str]] = {
    "gradient_clip_val": ((None, 0), "null", "Lightning clips no gradients there"),
    "accumulate_grad_batches": ((1,), "1", "Lightning accumulates no gradients there"),
}


def check_trainer_settings(cfg: DictConfig, callbacks: list[Callback]) -> None:
    """Refuse (one line naming the ``trainer.*`` key) what Lightning would refuse once ``fit``
    starts: gradient clipping or accumulation under manual optimization, checkpointing off
    beside a checkpoint callback (``callbacks`` as instantiated)."""
    trainer = cfg.get("trainer") or {}
    for name, (neutral, shown, why) in UNSUPPORTED.items():
        value = trainer.get(name, neutral[0])
        if value not in neutral:
            raise UssSlamError(f"trainer.{name}={value}: {MANUAL}; {why}; expected {shown}")
    savers = [type(c).__name__ for c in callbacks if isinstance(c, ModelCheckpoint)]
    if trainer.get("enable_checkpointing", True) is False and savers:
        raise UssSlamError(
            f"trainer.enable_checkpointing=false: the callbacks save checkpoints "
            f"({', '.join(savers)}); expected true, or callbacks=none for a run without them"
        )


def trainer_error(error: BaseException) -> UssSlamError | None:
    """Lightning's configuration error (``MisconfigurationException``, wrapped or not by
    Hydra's instantiation) as one line naming the ``trainer.*`` key its text quotes (``trainer``
    when it quotes none); None for any other error."""
    cause: BaseException | None = error
    while isinstance(cause, InstantiationException):
        cause = cause.__cause__
    if not isinstance(cause, MisconfigurationException):
        return None
    quoted = re.search(r"`(?:Trainer\()?([a-z_]+)=", str(cause))
    key = f"trainer.{quoted[1]}" if quoted else "trainer"
    return UssSlamError(f"{key}: {cause}")


def build_trainer(cfg: DictConfig, **kwargs: Any) -> Trainer:
    """``instantiate(cfg.trainer, **kwargs)``, a Lightning configuration error as one line."""
    try:
        return instantiate(cfg.trainer, **kwargs)
    except InstantiationException as error:
        named = trainer_error(error)
        if named is None:
            raise
        raise named from error

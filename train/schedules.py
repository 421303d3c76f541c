"""Polynomial learning-rate decay of DeepLab / the paper, stepped once per training iteration."""

from __future__ import annotations

from torch.optim import Optimizer
from torch.optim.lr_scheduler import LRScheduler


def poly_factor(iteration: int, max_iters: int, power: float) -> float:
    """``(1 - iteration / max_iters) ** power``, clamped at 0 past ``max_iters``."""
    return max(0.0, 1.0 - iteration / max_iters) ** power


class PolyLR(LRScheduler):
    """``lr_i = base_lr × (1 - i / max_iters) ** power`` for every parameter group.

    ``i`` is the scheduler's own counter (``last_epoch``), advanced by one ``step()`` per
    training iteration and saved in checkpoints; the closed form (no multiplicative chaining)
    makes a resumed schedule bit-identical to an uninterrupted one. Heads keep their 10× ratio
    because each group decays from its own base rate.
    """

    def __init__(
        self, optimizer: Optimizer, max_iters: int, power: float = 0.9, last_epoch: int = -1
    ) -> None:
        if max_iters <= 0:
            raise ValueError(f"max_iters must be positive, got {max_iters}")
        self.max_iters = max_iters
        self.power = power
        super().__init__(optimizer, last_epoch)

    def get_lr(self) -> list[float]:
        factor = poly_factor(self.last_epoch, self.max_iters, self.power)
        return [base * factor for base in self.base_lrs]

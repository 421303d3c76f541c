"""Polynomial learning-rate decay of DeepLab / the paper, stepped once per training iteration, and
its horizon: the reference code (AdaptSegNet, ADVENT) decays over 250k iterations and stops
earlier (150k, 120k), so by default a run's schedule reaches 0 only at ``max_iters × 250/150``."""

from __future__ import annotations

from torch.optim import Optimizer
from torch.optim.lr_scheduler import LRScheduler

from uss_slam.core.errors import UssSlamError

REFERENCE_SCHEDULE_ITERS = 250_000
"""Iterations of the poly schedule of the reference code (AdaptSegNet's ``NUM_STEPS``)."""
REFERENCE_STOP_ITERS = 150_000
"""Where the reference code stops training on that schedule (AdaptSegNet's ``NUM_STEPS_STOP``):
the learning rate is then ``(1 - 150/250) ** 0.9 = 0.44`` of its base."""


def poly_horizon(max_iters: int, total_iters: int | None = None) -> int:
    """The iteration at which the poly schedule of a run of ``max_iters`` iterations would reach
    0: ``total_iters``, or by default ``round(max_iters × 250/150)``, so that the run stops where
    the reference code stops on its schedule (learning rate 0.44× its base at the end).

    Raises:
        UssSlamError: ``total_iters`` is not an integer ``>= max_iters`` (a horizon before the
            end would train the last iterations at learning rate 0).
    """
    if total_iters is None:
        return round(max_iters * REFERENCE_SCHEDULE_ITERS / REFERENCE_STOP_ITERS)
    if isinstance(total_iters, bool) or not isinstance(total_iters, int) or total_iters < max_iters:
        raise UssSlamError(
            f"model.poly_total_iters must be null or an integer >= model.max_iters ({max_iters}), "
            f"got {total_iters!r}"
        )
    return total_iters


def poly_factor(iteration: int, max_iters: int, power: float) -> float:
    """``(1 - iteration / max_iters) ** power``, clamped at 0 past ``max_iters``."""
    return max(0.0, 1.0 - iteration / max_iters) ** power


class PolyLR(LRScheduler):
    """``lr_i = base_lr × (1 - i / max_iters) ** power`` for every parameter group.

    ``max_iters`` is the schedule's horizon (where the rate would reach 0), which may lie beyond
    the iteration where training stops (:func:`poly_horizon`).

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

"""Helpers of the scoring tests that compare with evo (installed with the dev extra on Python
>= 3.11; the tests that call these skip elsewhere)."""

from __future__ import annotations

from typing import Any


def evo_ape(ref: Any, est: Any, align: str) -> Any:
    """evo's translation APE of the associated trajectories ``ref`` and ``est``, aligned as
    ``uss-traj ate --align`` says: ``se3`` (rigid), ``sim3`` (with scale) or ``none``."""
    from evo import main_ape
    from evo.core.metrics import PoseRelation

    return main_ape.ape(
        ref,
        est,
        PoseRelation.translation_part,
        align=align != "none",
        correct_scale=align == "sim3",
    )

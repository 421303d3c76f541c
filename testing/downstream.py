"""The downstream ratio of a segmenter's masks in SLAM, read from a ``uss-experiments``
``runs.csv``: how much of the ATE gap between no filter and ground-truth masks a model's masks
close (``studies/adaptation_masks.py``, ``studies/mask_size_control.py``)."""

from __future__ import annotations

from typing import Any

SLAM_COLUMNS = (("harness", "semantic"), ("harness", "semantic_geometry"), ("orbslam3", "semantic"))
"""The (system, variant) SLAM runs with a model that :func:`slam_ratios` reads."""
STATIC = "static_xyz"
"""The sequence where nothing moves: the ratio there is ATE_model / ATE_none."""


def slam_ratios(runs: list[dict[str, Any]], sequence: str, model: str) -> dict[str, float | None]:
    """``{"<system>:<variant>": ratio}`` of one model on one sequence from ``runs.csv`` rows:
    the downstream ratio (ATE_none − ATE_model) / (ATE_none − ATE_oracle), or, on
    :data:`STATIC` (no walker to remove), ATE_model / ATE_none; None when a run is missing or
    failed (or the ground-truth masks gain nothing)."""

    def ate(system: str, variant: str, with_model: bool) -> float | None:
        for r in runs:
            if (r.get("kind"), r.get("system"), r.get("sequence"), r.get("variant")) != (
                "slam", system, sequence, variant
            ) or r.get("status") != "ok" or r.get("ate_rmse") in (None, ""):  # fmt: skip
                continue
            if (str(r["id"]).endswith("/" + model)) == with_model:
                return float(r["ate_rmse"])
        return None

    out: dict[str, float | None] = {}
    for system, variant in SLAM_COLUMNS:
        none, mine = ate(system, "none", False), ate(system, variant, True)
        ratio = None
        if none is not None and mine is not None:
            if sequence == STATIC:
                ratio = mine / none
            else:
                gt = ate(system, "oracle", False)
                if gt is not None and none - gt > 0:
                    ratio = (none - mine) / (none - gt)
        out[f"{system}:{variant}"] = ratio
    return out

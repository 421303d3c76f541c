"""The SLAM runs of one ``uss-slam`` call, without the ones that would change nothing.

``compare`` runs the unfiltered baseline, then each filter set into ``out_dir/<set>/``. A set
that repeats an earlier one would run again into the same sub-folder and replace its row of the
table; an empty set is the baseline, which runs anyway; ``filters`` is not read when ``compare``
is given. A filter configured so that it can flag no keypoint (the semantic filter without
dynamic classes) runs and changes nothing. Each is one warning line
(:func:`uss_slam.core.cli.warning`) before the first frame is read; the repeated runs are not
run.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from omegaconf import DictConfig, OmegaConf

from uss_slam.core.cli import warning

from .filters.build import build_filters

Run = tuple[str | None, list[str]]
"""``(sub-folder or None, filter names)`` of one SLAM run."""


def _listed(value: Any) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [value]
    return [str(v) for v in value]


def _set_text(names: Sequence[str]) -> str:
    return "[" + ",".join(names) + "]"


def checked_runs(
    cfg: DictConfig, runs: Sequence[Run], params: Mapping[str, Any] | None = None
) -> list[Run]:
    """``runs`` (as :func:`uss_slam.slam_eval.config.check` planned them) without the filter
    sets of ``compare`` that repeat the baseline or an earlier set, with one warning for each
    of those and for ``filters`` given beside ``compare``; and one warning for each filter of
    the kept runs that can flag no keypoint as configured (``params``: the filter nodes)."""
    compare = OmegaConf.select(cfg, "compare")
    kept: list[Run] = []
    if compare is None:
        kept = list(runs)
    else:
        filters = _listed(OmegaConf.select(cfg, "filters"))
        if filters:
            warning(
                f"filters={_set_text(filters)} is not used: with compare, each set of compare "
                "names its filters and the baseline runs without any (drop filters, or add "
                f"{_set_text(filters)} to compare)"
            )
        seen: dict[tuple[str, ...], int] = {}
        for position, (name, names) in enumerate(runs):
            key = tuple(names)
            index = position - 1  # runs[0] is the baseline, runs[k] is compare[k - 1]
            if key in seen:
                first = seen[key]
                what = (
                    "is empty: the baseline, which runs anyway"
                    if first < 0
                    else f"{_set_text(names)} repeats compare[{first}], which runs once"
                )
                warning(f"compare[{index}] {what}; compare[{index}] is left out")
                continue
            seen[key] = index
            kept.append((name, list(names)))
    used = sorted({n for _, names in kept for n in names})
    for flt, name in zip(build_filters(used, params), used, strict=True):
        reason = flt.idle_reason()
        if reason is not None:
            warning(f"slam.filter_params.{name}.{reason}")
    return kept

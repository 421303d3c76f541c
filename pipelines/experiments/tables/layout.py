"""What the tables show (:class:`Layout`, read from the rows) and the selection of rows."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..grid import ADABN, ADAPTED, ORACLE
from .runs_csv import ALL_SEQUENCES, SOURCE_VAL


@dataclass(frozen=True)
class Layout:
    """What the tables show: names in the grid's order."""

    configs: tuple[str, ...]  # every training config (T1 rows)
    sequences: tuple[str, ...]
    systems: tuple[str, ...]
    variants: tuple[str, ...]
    source_only: str | None  # the "without ATL" config of T2 / the ratio
    adapted: tuple[str, ...]  # the "with ATL" config(s): adapted with tables.n_layers
    methods: tuple[str, ...] = ()  # one config per method at tables.n_layers (T2 by method)
    crf_configs: tuple[str, ...] = ()  # configs with dense-CRF runs or segmentation metrics
    adabn: tuple[str, ...] = ()  # T0's AdaBN configs (one per source-only config)
    oracle: str | None = None  # T0's target oracle


def layout_from_rows(rows: Sequence[Mapping[str, Any]], n_layers: int | None) -> Layout:
    """The layout implied by the rows (names in order of first appearance)."""

    def ordered(key: str, kind: str | None = None) -> tuple[str, ...]:
        return tuple(
            dict.fromkeys(
                r[key]
                for r in rows
                if r.get(key) is not None and (kind is None or r["kind"] == kind)
            )
        )

    trains = [r for r in select(rows, kind="train") if r.get("method") != ORACLE]
    configs = tuple(dict.fromkeys(r["config"] for r in trains if r.get("config") is not None))
    source_only = next((r["config"] for r in trains if r["method"] == "source_only"), None)
    adapted = tuple(
        dict.fromkeys(
            r["config"] for r in trains if r["method"] == ADAPTED and r["n_layers"] == n_layers
        )
    )
    sequences = tuple(s for s in ordered("sequence") if s not in (ALL_SEQUENCES, SOURCE_VAL))
    methods = tuple(
        dict.fromkeys(r["config"] for r in trains if r.get("n_layers") in (None, n_layers))
    )
    crf_configs = tuple(
        dict.fromkeys(
            r["config"]
            for r in rows
            if r.get("crf") and r.get("config") is not None and r["kind"] in ("segeval", "slam")
        )
    )
    adabn = tuple(
        dict.fromkeys(r["config"] for r in rows if r.get("method") == ADABN and r.get("config"))
    )
    oracle = next(
        (r["config"] for r in rows if r["kind"] == "train" and r["method"] == ORACLE), None
    )
    return Layout(
        configs,
        sequences,
        ordered("system", "slam"),
        ordered("variant", "slam"),
        source_only,
        adapted,
        methods,
        crf_configs,
        adabn,
        oracle,
    )


def select(rows: Sequence[Mapping[str, Any]], **where: Any) -> list[Mapping[str, Any]]:
    return [r for r in rows if all(r.get(k) == v for k, v in where.items())]


def seg_rows(rows, config: str, sequence: str, crf: bool = False) -> list[Mapping[str, Any]]:
    """Segmentation rows of ``config`` (with the dense CRF when ``crf``)."""
    return [
        r
        for r in select(rows, kind="segeval", config=config, sequence=sequence)
        if bool(r.get("crf")) == crf
    ]


def slam_rows(rows, system: str, sequence: str, variant: str, config: str | None = None):
    return select(
        rows, kind="slam", system=system, sequence=sequence, variant=variant, config=config
    )

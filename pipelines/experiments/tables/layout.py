"""What the tables show (:class:`Layout`, read from the rows) and the selection of rows."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from uss_slam.pipelines.runs import USES_TARGET_LABELS

from ..grid import ADABN, ADAPTED, ORACLE, TARGET_LABEL_USES
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
    target_labels: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """Config -> what of its model was chosen with target labels (:func:`target_label_uses`)."""

    def name(self, config: str) -> str:
        """``config``, with `` †`` when it was chosen with target labels."""
        return f"{config} †" if self.target_labels.get(config) else config

    def footnote(self, configs: Iterable[str | None]) -> list[str]:
        """The footnote of a table showing ``configs`` (``[]`` when none is marked)."""
        return [DAGGER_NOTE, ""] if any(self.target_labels.get(c) for c in configs if c) else []


DAGGER_NOTE = "† chosen with target labels"


def target_label_uses(
    rows: Sequence[Mapping[str, Any]], policy: str = "last"
) -> dict[str, tuple[str, ...]]:
    """Config -> what of its model was chosen with target labels, in the order of
    :data:`~uss_slam.pipelines.experiments.grid.TARGET_LABEL_USES`: the ``target_labels`` column
    of its rows; and, for a runs.csv without the column too, the oracle's training and a
    checkpoint ``policy`` that reads target labels (every model's checkpoint)."""
    found: dict[str, set[str]] = {}
    for r in rows:
        if r.get("config") is None:
            continue
        uses = found.setdefault(r["config"], set())
        uses.update(r["target_labels"].split(";") if r.get("target_labels") else ())
        uses.update(["training"] if r.get("method") == ORACLE else [])
        uses.update(["checkpoint selection"] if policy in USES_TARGET_LABELS else [])
    return {c: tuple(u for u in TARGET_LABEL_USES if u in uses) for c, uses in found.items()}


def layout_from_rows(
    rows: Sequence[Mapping[str, Any]], n_layers: int | None, policy: str = "last"
) -> Layout:
    """The layout implied by the rows (names in order of first appearance); ``policy``: the
    trainings' checkpoint policy (``train.checkpoint``), for the rows' † marks."""

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
        target_label_uses(rows, policy),
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

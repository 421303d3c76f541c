"""The paper's tables from ``runs.csv`` (one row per job of the grid): mean ± s.d. over seeds.

- **T0** the standard UDA table: source-only, AdaBN, each method and the target oracle, each
  with its source validation mIoU (in domain), target mIoU, person IoU and person-mask frame
  metrics (means over the evaluation sequences) and its closure ``(row − source-only) /
  (oracle − source-only)`` paired by seed; mean ± s.e. over seeds and every seed's value;
- **T1** discriminator depth: target mIoU and per-class IoU of every configuration (source-only,
  adapted with n = 4..7), and its ATE RMSE per sequence (semantic filter);
- **T2** "ATL" (with / without adversarial transfer learning): per sequence, mIoU, the person-mask
  frame metrics (FPR, FNR, recall, precision, PWC) and ATE RMSE / mean / median / S.D. of
  source-only against adapted, with the improvement % the paper prints
  (``(without − with) / without`` for errors, ``(with − without) / without`` for scores);
- **T3** "MVG" (with / without multi-view geometry): semantic against semantic+geometry (and
  +object) of the adapted model, with the improvement %;
- baselines (no filter, geometry alone, ground-truth masks) and the downstream ratio
  ``(ATE_none − ATE_model) / (ATE_none − ATE_oracle)`` per sequence and seed (1 = as good as
  ground-truth masks, 0 = no better than no filter);
- failures: every job that failed, was blocked by a failed job, or left no result, and why.

Each cell is ``mean ± s.d. (n=k)`` over the seeds whose job succeeded (sample s.d., ``n − 1``);
a cell with failed jobs says how many (``n=2, 1 failed``); a cell with none says ``failed``.
Pure Python + numpy (matplotlib for the plots only).
"""

from __future__ import annotations

import csv
import json
import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import DataFormatError
from uss_slam.core.files import write_text_atomic
from uss_slam.pipelines.runs import USES_TARGET_LABELS

from .grid import ADABN, ADAPTED, ORACLE, VARIANTS

RATES = ("FPR", "FNR", "recall", "precision", "PWC")
ATE_KEYS = ("ate_rmse", "ate_mean", "ate_median", "ate_std")
REPEAT_COLUMNS = ("ate_runs", "ate_rmse_min", "ate_rmse_max")
"""A SLAM job's repeated runs (``slam.repeats``, ORB-SLAM3's): how many gave an ATE, and the
smallest and largest ATE RMSE among them (``ate_rmse`` is the median run's)."""
COLUMNS: tuple[str, ...] = (
    "kind",
    "id",
    "status",
    "reason",
    "method",
    "n_layers",
    "loss",
    "config",
    "seed",
    "system",
    "sequence",
    "variant",
    "val_mIoU",
    "mIoU",
    *(f"IoU_{c}" for c in CLASS_NAMES),
    *(f"person_{r}" for r in RATES),
    *ATE_KEYS,
    *REPEAT_COLUMNS,
    "tracked_fraction",
    "fps",
    "segmentation_ms",
    "crf_ms",
    "total_ms",
    "crf",
    "seconds",
    "folder",
)
"""The columns of ``runs.csv``, in order."""
TIMING_COLUMNS = {
    "segmentation_ms": "segmentation",
    "crf_ms": "segmentation.crf",
    "total_ms": "total",
}
"""``runs.csv`` column -> key of a SLAM run's ``timing_ms`` (mean wall ms per processed frame;
``segmentation`` includes the CRF's ``segmentation.crf``)."""
INT_COLUMNS = ("n_layers", "seed", "crf", "ate_runs")
TEXT_COLUMNS = (
    "kind",
    "id",
    "status",
    "reason",
    "method",
    "loss",
    "config",
    "system",
    "sequence",
    "variant",
    "folder",
)
STATUSES = ("ok", "failed", "blocked", "missing")
ALL_SEQUENCES = "all"
"""``sequence`` of a segeval row pooled over every evaluation sequence."""
SOURCE_VAL = "source_val"
"""``sequence`` of a segeval row on the source validation split (T0's in-domain column)."""

LOWER_IS_BETTER = {"person_FPR", "person_FNR", "person_PWC", *ATE_KEYS}
LABELS = {
    "mIoU": "mIoU",
    "val_mIoU": "val mIoU",
    **{f"person_{r}": f"person {r}" for r in RATES},
    "ate_rmse": "ATE RMSE [m]",
    "ate_mean": "ATE mean [m]",
    "ate_median": "ATE median [m]",
    "ate_std": "ATE S.D. [m]",
}


# ---------------------------------------------------------------------------------- runs.csv


def write_runs(path: Path, rows: Iterable[Mapping[str, Any]]) -> None:
    """``runs.csv`` with :data:`COLUMNS` (empty cell = no value)."""
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="raise")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if row.get(k) is None else row[k] for k in COLUMNS})
    tmp.replace(path)


def read_runs(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``runs.csv`` with numbers as int / float and empty cells as None."""
    try:
        text = path.read_text()
    except OSError as error:
        raise DataFormatError(path, f"cannot read runs table ({error.strerror})") from None
    reader = csv.DictReader(text.splitlines())
    missing = [c for c in ("kind", "id", "status") if c not in (reader.fieldnames or [])]
    if missing:
        raise DataFormatError(path, f"missing column(s) {', '.join(missing)}", line=1)
    rows = []
    for line, raw in enumerate(reader, start=2):
        row: dict[str, Any] = {}
        for key, value in raw.items():
            if key is None:
                raise DataFormatError(path, "more cells than columns", line=line)
            if value is None or value == "":
                row[key] = None
            elif key in TEXT_COLUMNS:
                row[key] = value
            else:
                try:
                    row[key] = int(value) if key in INT_COLUMNS else float(value)
                except ValueError:
                    raise DataFormatError(
                        path, f"column {key}: expected a number, got {value!r}", line=line
                    ) from None
        if row.get("status") not in STATUSES:
            raise DataFormatError(
                path,
                f"column status: expected one of {', '.join(STATUSES)}, got {row.get('status')!r}",
                line=line,
            )
        rows.append(row)
    return rows


# ---------------------------------------------------------------------------------- statistics


@dataclass(frozen=True)
class Stat:
    """A table cell: the values of the successful jobs, and how many jobs gave none."""

    values: tuple[float, ...]
    failed: int = 0  # jobs failed, blocked or without a result
    undefined: int = 0  # jobs that succeeded without a value for this metric

    @property
    def n(self) -> int:
        return len(self.values)

    @property
    def mean(self) -> float | None:
        return statistics.fmean(self.values) if self.values else None

    @property
    def sd(self) -> float | None:
        """Sample standard deviation (``n − 1``); None for fewer than two values."""
        return statistics.stdev(self.values) if len(self.values) > 1 else None

    @property
    def se(self) -> float | None:
        """Standard error of the mean (``s.d. / √n``); None for fewer than two values."""
        sd = self.sd
        return None if sd is None else sd / math.sqrt(self.n)

    def text(self, digits: int = 4, spread: str = "sd") -> str:
        """``mean ± s.d. (n=k)`` (``spread="se"``: ± the standard error), with how many jobs
        failed or gave no value."""
        notes = [f"{self.failed} failed"] if self.failed else []
        notes += [f"{self.undefined} n/a"] if self.undefined else []
        if not self.values:
            if self.failed:
                return "failed" + (f" ({self.failed})" if self.failed > 1 else "")
            return "n/a" if self.undefined else "—"
        body = f"{self.mean:.{digits}f}"
        width = self.se if spread == "se" else self.sd
        if width is not None:
            body += f" ± {width:.{digits}f}"
        return f"{body} (n={self.n}{''.join(', ' + n for n in notes)})"

    def as_json(self) -> dict[str, Any]:
        return {
            "mean": self.mean,
            "sd": self.sd,
            "n": self.n,
            "failed": self.failed,
            "undefined": self.undefined,
            "values": list(self.values),
        }


def stat(rows: Iterable[Mapping[str, Any]], key: str) -> Stat:
    """The :class:`Stat` of column ``key`` over ``rows``."""
    values, failed, undefined = [], 0, 0
    for row in rows:
        if row["status"] != "ok":
            failed += 1
        elif row.get(key) is None or (isinstance(row[key], float) and math.isnan(row[key])):
            undefined += 1
        else:
            values.append(float(row[key]))
    return Stat(tuple(values), failed, undefined)


def improvement(without: Stat, with_: Stat, key: str) -> float | None:
    """The paper's improvement % of the means: positive = ``with_`` is better."""
    a, b = without.mean, with_.mean
    if a is None or b is None or a == 0:
        return None
    gain = (a - b) if key in LOWER_IS_BETTER else (b - a)
    return 100.0 * gain / abs(a)


def _pct(value: float | None) -> str:
    return "—" if value is None else f"{value:.2f}%"


def _select(rows: Sequence[Mapping[str, Any]], **where: Any) -> list[Mapping[str, Any]]:
    return [r for r in rows if all(r.get(k) == v for k, v in where.items())]


def _digits(key: str) -> int:
    return 4 if key.startswith("ate_") else 3


def _md(header: Sequence[str], body: Iterable[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    return lines


# ---------------------------------------------------------------------------------- T0


@dataclass(frozen=True)
class SeedValues:
    """One T0 cell: each seed's value, and how many seeds gave none (failed / undefined)."""

    values: Mapping[int, float]
    failed: int = 0
    undefined: int = 0

    @property
    def stat(self) -> Stat:
        ordered = tuple(self.values[s] for s in sorted(self.values))
        return Stat(ordered, self.failed, self.undefined)

    def as_json(self) -> dict[str, Any]:
        s = self.stat
        return {**s.as_json(), "se": s.se, "per_seed": {str(k): v for k, v in self.values.items()}}


def seed_means(
    rows: Sequence[Mapping[str, Any]], config: str, key: str, sequences: Sequence[str]
) -> SeedValues:
    """Per seed, the mean of column ``key`` over the segmentation rows of ``config`` on
    ``sequences`` (no CRF) where it is defined; a seed whose evaluation has no result counts as
    failed, one without a defined value as undefined."""
    by_seed: dict[int, list[Mapping[str, Any]]] = {}
    for r in _select(rows, kind="segeval", config=config):
        if r.get("sequence") in sequences and not r.get("crf") and r.get("seed") is not None:
            by_seed.setdefault(int(r["seed"]), []).append(r)
    values: dict[int, float] = {}
    failed = undefined = 0
    for seed in sorted(by_seed):
        seed_rows = by_seed[seed]
        if any(r["status"] != "ok" for r in seed_rows):
            failed += 1
            continue
        defined = [float(r[key]) for r in seed_rows if _defined(r.get(key))]
        if defined:
            values[seed] = statistics.fmean(defined)
        else:
            undefined += 1
    return SeedValues(values, failed, undefined)


def _defined(value: Any) -> bool:
    return value is not None and not (isinstance(value, float) and math.isnan(value))


def closure(value: float | None, source_only: float | None, oracle: float | None) -> float | None:
    """``(value − source-only) / (oracle − source-only)``: 0 = no better than source-only, 1 =
    as good as the target oracle; None when a value is missing or the oracle is no better than
    source-only (the ratio is then meaningless)."""
    if value is None or source_only is None or oracle is None or oracle - source_only <= 0:
        return None
    return (value - source_only) / (oracle - source_only)


def paired_closure(row: SeedValues, source_only: SeedValues, oracle: SeedValues) -> SeedValues:
    """The closure of each seed of ``row`` against source-only and the oracle of the *same*
    seed; a seed without all three (or whose oracle is no better) is undefined."""
    values: dict[int, float] = {}
    undefined = 0
    for seed, value in row.values.items():
        c = closure(value, source_only.values.get(seed), oracle.values.get(seed))
        if c is None:
            undefined += 1
        else:
            values[seed] = c
    return SeedValues(values, row.failed, row.undefined + undefined)


T0_SEG = ("mIoU", "IoU_person")
T0_FRAMES = tuple(f"person_{r}" for r in RATES)


def t0_rows(layout: Layout) -> list[tuple[str, str]]:
    """T0's rows in order, ``(config, role)``: source-only, AdaBN, each method at the tables'
    depth, the target oracle."""
    if layout.source_only is None:
        return []
    rows = [(layout.source_only, "source-only")]
    own = {c.removesuffix(f"_{ADABN}"): c for c in layout.adabn if c.endswith(f"_{ADABN}")}
    rows += [(c, "AdaBN") for c in layout.adabn if c not in own.values()]
    for c in layout.methods:
        if c != layout.source_only:
            rows.append((c, "method"))
            if c in own:  # the method's checkpoint with target statistics, right after it
                rows.append((own[c], "AdaBN"))
    rows += [(layout.oracle, "oracle")] if layout.oracle else []
    return rows


def target_labels(role: str, policy: str) -> str:
    """What target labels a T0 row used: the oracle's training, and the checkpoint selection
    of a policy that reads them (``train.checkpoint=best_target_val``)."""
    used = ["training"] if role == "oracle" else []
    used += ["checkpoint selection"] if policy in USES_TARGET_LABELS else []
    return ", ".join(used) or "none"


def table_t0(rows, layout: Layout, policy: str = "last") -> tuple[dict[str, Any], list[str]]:
    """T0, the standard UDA table (module docstring)."""
    title = "### T0: the UDA table (source-only, AdaBN, methods, target oracle)"
    order = t0_rows(layout)
    if not order:
        return {"rows": []}, [title, "", "Not computed: needs source_only in grid.methods.", ""]
    sequences = layout.sequences
    cells: dict[str, dict[str, SeedValues]] = {}
    for config, _ in order:
        cells[config] = {
            "source_val_mIoU": seed_means(rows, config, "mIoU", (SOURCE_VAL,)),
            **{k: seed_means(rows, config, k, sequences) for k in (*T0_SEG, *T0_FRAMES)},
        }
    so = cells[layout.source_only]
    none = SeedValues({})
    oracle = cells[layout.oracle] if layout.oracle else None
    for config, _ in order:
        for k in T0_SEG:
            cells[config][f"closure_{k}"] = (
                paired_closure(cells[config][k], so[k], oracle[k]) if oracle else none
            )
    main = ("source_val_mIoU", "mIoU", "IoU_person", "closure_mIoU", "closure_IoU_person")
    systems = list(layout.systems)
    data: dict[str, Any] = {
        "source_only": layout.source_only,
        "oracle": layout.oracle,
        "sequences": list(sequences),
        "policy": policy,
        "rows": [],
    }
    body, per_seed, frames = [], [], []
    for config, role in order:
        labels = target_labels(role, policy)
        name = config + (" †" if labels != "none" else "")
        c = cells[config]
        ate = {
            (system, seq): stat(_slam_rows(rows, system, seq, "semantic", config), "ate_rmse")
            for system in systems
            for seq in sequences
        }
        data["rows"].append(
            {
                "config": config,
                "role": role,
                "target_labels": labels,
                **{k: v.as_json() for k, v in c.items()},
                "ate_rmse": [
                    {"system": system, "sequence": seq, **s.as_json(), "se": s.se}
                    for (system, seq), s in ate.items()
                ],
            }
        )
        body.append([name, labels, *(c[k].stat.text(3, "se") for k in main)])
        frames.append(
            [
                name,
                *(c[k].stat.text(3, "se") for k in T0_FRAMES),
                *(s.text(4, "se") for s in ate.values()),
            ]
        )
        seeds = sorted(
            {int(r["seed"]) for r in _select(rows, config=config) if r.get("seed") is not None}
        )
        for seed in seeds:
            per_seed.append([config, str(seed), *(_value(c[k].values.get(seed)) for k in main)])
    header = [
        "row",
        "target labels used",
        "source val mIoU (in domain)",
        "target mIoU",
        "person IoU",
        "closure (mIoU)",
        "closure (person IoU)",
    ]
    lines = [
        title,
        "",
        "source-only: the source-only model (source BatchNorm statistics); adabn: the same "
        "checkpoint with BatchNorm statistics of unlabelled target training frames (AdaBN, the "
        "baseline any method must beat); each method at tables.n_layers (<method>_adabn: its "
        "checkpoint with those target statistics, grid.adabn_methods); oracle: source-only "
        "trained on the labelled target training frames (the same net, budget and crops). "
        "Source val mIoU: on the source validation split (in domain for source-only). Target "
        "mIoU and person IoU: the mean over the evaluation sequences where defined "
        f"({', '.join(sequences)}). Closure = (row − source-only) / (oracle − source-only), "
        "per seed against the same seed's source-only and oracle (0 = no gain, 1 = the "
        "oracle's; n/a when the oracle is no better than source-only)"
        + ("" if layout.oracle else "; no oracle in this run (grid.oracle=false): no closure")
        + ". Each cell: mean ± standard error over seeds (n = seeds with a value); the per-seed "
        "table has every seed's value. † = target labels used (column 2).",
        "",
        *_md(header, body),
        "",
        "#### T0 per seed",
        "",
        *_md(["row", "seed", *header[2:]], per_seed),
        "",
        "#### T0 person masks and SLAM",
        "",
        "Person-mask frame metrics (as in T2; mean over the evaluation sequences) and ATE RMSE "
        "[m] with the semantic filter; mean ± standard error over seeds.",
        "",
        *_md(
            [
                "row",
                *(LABELS[k] for k in T0_FRAMES),
                *(
                    f"ATE {seq}" + (f" ({system})" if len(systems) > 1 else "")
                    for system in systems
                    for seq in sequences
                ),
            ],
            frames,
        ),
        "",
    ]
    return data, lines


def _value(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f}"


# ---------------------------------------------------------------------------------- tables


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

    trains = [r for r in _select(rows, kind="train") if r.get("method") != ORACLE]
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


def _seg_rows(rows, config: str, sequence: str, crf: bool = False) -> list[Mapping[str, Any]]:
    """Segmentation rows of ``config`` (with the dense CRF when ``crf``)."""
    return [
        r
        for r in _select(rows, kind="segeval", config=config, sequence=sequence)
        if bool(r.get("crf")) == crf
    ]


def points(stat_: Stat, reference: Stat) -> float | None:
    """The difference of the means in points (100 × the difference of two rates / IoUs)."""
    if stat_.mean is None or reference.mean is None:
        return None
    return 100.0 * (stat_.mean - reference.mean)


def _points(value: float | None) -> str:
    return "—" if value is None else f"{value:+.2f}"


def _slam_rows(rows, system: str, sequence: str, variant: str, config: str | None = None):
    return _select(
        rows, kind="slam", system=system, sequence=sequence, variant=variant, config=config
    )


def table_t1(rows, layout: Layout) -> tuple[dict[str, Any], list[str]]:
    classes = [f"IoU_{c}" for c in CLASS_NAMES]
    seg_keys = ["val_mIoU", "mIoU", *classes]
    data: dict[str, Any] = {"segmentation": [], "ate_rmse": []}
    body = []
    reference = (
        stat(_seg_rows(rows, layout.source_only, ALL_SEQUENCES), "mIoU")
        if layout.source_only is not None
        else Stat(())
    )
    for config in layout.configs:
        seg = _seg_rows(rows, config, ALL_SEQUENCES)
        val = _select(rows, kind="train", config=config)
        stats = {"val_mIoU": stat(val, "val_mIoU"), **{k: stat(seg, k) for k in seg_keys[1:]}}
        delta = points(stats["mIoU"], reference)
        data["segmentation"].append(
            {
                "config": config,
                **{k: s.as_json() for k, s in stats.items()},
                "mIoU_vs_source_only_points": delta,
            }
        )
        body.append(
            [
                config,
                stats["val_mIoU"].text(3),
                stats["mIoU"].text(3),
                _points(delta),
                *(stats[k].text(3) for k in classes),
            ]
        )
    header = [
        "configuration",
        "val mIoU",
        "target mIoU",
        "Δ mIoU [points]",
        *(f"IoU {c}" for c in CLASS_NAMES),
    ]
    lines = [
        "### T1a: segmentation by discriminator depth",
        "",
        "Target mIoU and per-class IoU on the labelled frames of every evaluation sequence "
        "(pooled); val mIoU = the exported checkpoint's target validation mIoU; Δ mIoU = target "
        "mIoU minus source-only's, in points (100 × the difference of the means).",
        "",
        *_md(header, body),
        "",
    ]
    for system in layout.systems:
        body = []
        for config in layout.configs:
            cells = []
            for sequence in layout.sequences:
                s = stat(_slam_rows(rows, system, sequence, "semantic", config), "ate_rmse")
                data["ate_rmse"].append(
                    {"system": system, "config": config, "sequence": sequence, **s.as_json()}
                )
                cells.append(s.text(4))
            body.append([config, *cells])
        lines += [
            f"### T1b: ATE RMSE [m] by discriminator depth ({system}, semantic filter)",
            "",
            *_md(["configuration", *layout.sequences], body),
            "",
        ]
    return data, lines


T2_SEG = ("mIoU", *(f"person_{r}" for r in RATES))


def table_t2(rows, layout: Layout) -> tuple[dict[str, Any], list[str]]:
    data: dict[str, Any] = {"per_sequence": [], "improvement": []}
    lines: list[str] = []
    if layout.source_only is None or not layout.adapted:
        return data, [
            "### T2: with / without ATL",
            "",
            "Not computed: the grid needs source_only and adaptsegnet with tables.n_layers.",
            "",
        ]
    so = layout.source_only
    summary: dict[tuple[str, str], list[str]] = {}
    for adapted in layout.adapted:
        lines += [
            f"### T2: without ATL ({so}) vs with ATL ({adapted})",
            "",
            "Person-mask metrics count frames (the robust-semantic-mapping paper's "
            "Table III: a frame is a true positive when the predicted person mask has IoU "
            ">= 0.5 with the true one); ATE with the semantic filter. Improvement: "
            "positive = better with ATL.",
            "",
        ]
        for sequence in layout.sequences:
            metrics: list[tuple[str, str, list, list]] = [
                (
                    key,
                    LABELS[key],
                    _seg_rows(rows, so, sequence),
                    _seg_rows(rows, adapted, sequence),
                )
                for key in T2_SEG
            ]
            for system in layout.systems:
                for key in ATE_KEYS:
                    metrics.append(
                        (
                            key,
                            f"{LABELS[key]} ({system})",
                            _slam_rows(rows, system, sequence, "semantic", so),
                            _slam_rows(rows, system, sequence, "semantic", adapted),
                        )
                    )
            body = []
            for key, label, without_rows, with_rows in metrics:
                without, with_ = stat(without_rows, key), stat(with_rows, key)
                gain = improvement(without, with_, key)
                data["per_sequence"].append(
                    {
                        "sequence": sequence,
                        "metric": label,
                        "without": without.as_json(),
                        "with": with_.as_json(),
                        "improvement_pct": gain,
                        "without_config": so,
                        "with_config": adapted,
                    }
                )
                body.append(
                    [label, without.text(_digits(key)), with_.text(_digits(key)), _pct(gain)]
                )
                summary.setdefault((adapted, label), []).append(_pct(gain))
            lines += [
                f"#### {sequence}",
                "",
                *_md(["metric", "without ATL", "with ATL", "improvement"], body),
                "",
            ]
    lines += [
        "### T2 summary: improvement with ATL per sequence",
        "",
        "The improvement % of the means (the paper's Table 5 layout).",
        "",
    ]
    body = [
        [f"{label} ({adapted})" if len(layout.adapted) > 1 else label, *cells]
        for (adapted, label), cells in summary.items()
    ]
    for (adapted, label), cells in summary.items():
        data["improvement"].append(
            {
                "with_config": adapted,
                "metric": label,
                "per_sequence": dict(zip(layout.sequences, cells, strict=True)),
            }
        )
    lines += [*_md(["metric", *layout.sequences], body), ""]
    return data, lines


def table_t3(rows, layout: Layout) -> tuple[dict[str, Any], list[str]]:
    data: list[dict[str, Any]] = []
    lines: list[str] = []
    if not layout.adapted or "semantic" not in layout.variants:
        return {"rows": data}, [
            "### T3: with / without multi-view geometry",
            "",
            "Not computed: needs the semantic variant and the adapted model of tables.n_layers.",
            "",
        ]
    extra = [v for v in ("semantic_geometry", "semantic_geometry_object") if v in layout.variants]
    for adapted in layout.adapted:
        for system in layout.systems:
            has = [v for v in extra if _select(rows, kind="slam", system=system, variant=v)]
            if "semantic_geometry" not in has:
                continue
            header = ["sequence", "metric", "semantic", "semantic+geometry", "improvement"]
            header += ["semantic+geometry+object"] if "semantic_geometry_object" in has else []
            body = []
            for sequence in layout.sequences:
                for key in ATE_KEYS:
                    sem = stat(_slam_rows(rows, system, sequence, "semantic", adapted), key)
                    geo = stat(
                        _slam_rows(rows, system, sequence, "semantic_geometry", adapted), key
                    )
                    gain = improvement(sem, geo, key)
                    cells = [sequence, LABELS[key], sem.text(4), geo.text(4), _pct(gain)]
                    entry = {
                        "system": system,
                        "config": adapted,
                        "sequence": sequence,
                        "metric": key,
                        "semantic": sem.as_json(),
                        "semantic_geometry": geo.as_json(),
                        "improvement_pct": gain,
                    }
                    if "semantic_geometry_object" in has:
                        obj = stat(
                            _slam_rows(rows, system, sequence, "semantic_geometry_object", adapted),
                            key,
                        )
                        cells.append(obj.text(4))
                        entry["semantic_geometry_object"] = obj.as_json()
                    body.append(cells)
                    data.append(entry)
            lines += [
                f"### T3: without / with multi-view geometry ({adapted}, {system})",
                "",
                "Improvement: positive = better with geometry.",
                "",
                *_md(header, body),
                "",
            ]
    if not lines:
        lines = [
            "### T3: with / without multi-view geometry",
            "",
            "Not computed: no semantic_geometry runs (variants).",
            "",
        ]
    return {"rows": data}, lines


def table_methods(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    """T2 by method: one row per method at the tables' depth, with its difference to
    source-only in points."""
    data: list[dict[str, Any]] = []
    if layout.source_only is None or len(layout.methods) < 2:
        return data, []
    so = layout.source_only
    seg_keys = ("mIoU", "IoU_person")
    reference = {k: stat(_seg_rows(rows, so, ALL_SEQUENCES), k) for k in seg_keys}
    lines = [
        "### T2 by method: adapted vs source-only",
        "",
        "One row per method (discriminator depth = tables.n_layers): target mIoU and person "
        "IoU (pooled over the labelled evaluation frames) with their difference to source-only "
        "in points (100 × the difference of the means), ATE RMSE [m] with the semantic filter.",
        "",
    ]
    systems = list(layout.systems)
    header = ["configuration", "target mIoU", "Δ mIoU [points]", "IoU person", "Δ [points]"]
    header += [
        f"ATE {seq}" + (f" ({system})" if len(systems) > 1 else "")
        for system in systems
        for seq in layout.sequences
    ]
    body = []
    for config in layout.methods:
        seg = {k: stat(_seg_rows(rows, config, ALL_SEQUENCES), k) for k in seg_keys}
        entry: dict[str, Any] = {"config": config}
        cells = [config]
        for k in seg_keys:
            delta = points(seg[k], reference[k])
            entry[k] = seg[k].as_json()
            entry[f"{k}_vs_source_only_points"] = delta
            cells += [seg[k].text(3), _points(delta)]
        entry["ate_rmse"] = []
        for system in systems:
            for sequence in layout.sequences:
                s_ = stat(_slam_rows(rows, system, sequence, "semantic", config), "ate_rmse")
                entry["ate_rmse"].append({"system": system, "sequence": sequence, **s_.as_json()})
                cells.append(s_.text(4))
        data.append(entry)
        body.append(cells)
    return data, [*lines, *_md(header, body), ""]


CRF_PAIRS = (("semantic", "semantic_crf"), ("semantic_geometry", "semantic_geometry_crf"))
"""(filter variant, the same with the dense CRF)."""


def table_crf(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    """Dense CRF off / on: segmentation metrics and ATE of each model with CRF runs."""
    data: list[dict[str, Any]] = []
    pairs = [(off, on) for off, on in CRF_PAIRS if on in layout.variants]
    if not layout.crf_configs:
        return data, []
    seg_keys = ("mIoU", "IoU_person", "person_FNR", "person_FPR")
    lines: list[str] = []
    for system in layout.systems:
        header = ["configuration", "filter", "CRF", "target mIoU", "IoU person", "person FNR"]
        header += ["person FPR", *(f"ATE {s}" for s in layout.sequences)]
        body = []
        for config in layout.crf_configs:
            for off, on in pairs or [("semantic", "semantic_crf")]:
                for crf, variant in ((False, off), (True, on)):
                    seg = {
                        k: stat(_seg_rows(rows, config, ALL_SEQUENCES, crf=crf), k)
                        for k in seg_keys
                    }
                    ate = {
                        seq: stat(_slam_rows(rows, system, seq, variant, config), "ate_rmse")
                        for seq in layout.sequences
                    }
                    data.append(
                        {
                            "system": system,
                            "config": config,
                            "filter": off,
                            "crf": crf,
                            **{k: v.as_json() for k, v in seg.items()},
                            "ate_rmse": {seq: v.as_json() for seq, v in ate.items()},
                        }
                    )
                    body.append(
                        [
                            config,
                            VARIANTS[off].label,
                            "on" if crf else "off",
                            *(seg[k].text(3) for k in seg_keys),
                            *(ate[seq].text(4) for seq in layout.sequences),
                        ]
                    )
        lines += [
            f"### Dense CRF off / on ({system})",
            "",
            "The same exported model without and with the dense-CRF refinement of its output "
            "(uss-slam segmenter.crf=true): segmentation metrics pooled over the labelled "
            "evaluation frames, ATE RMSE [m] per sequence; its time is in the timing table.",
            "",
            *_md(header, body),
            "",
        ]
    return data, lines


def table_timing(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    """Mean wall ms per frame of the SLAM runs of each variant: segmentation (the segmenter's
    whole cost), its dense CRF, the whole run."""
    data: list[dict[str, Any]] = []
    if not any(r.get("total_ms") is not None for r in _select(rows, kind="slam")):
        return data, []  # a runs.csv from before the timing columns
    lines: list[str] = []
    keys = ("segmentation_ms", "crf_ms", "total_ms", "fps")
    for system in layout.systems:
        body = []
        for variant in layout.variants:
            runs = _select(rows, kind="slam", system=system, variant=variant)
            stats = {k: stat(runs, k) for k in keys}
            if variant not in VARIANTS or not VARIANTS[variant].crf:
                stats["crf_ms"] = Stat(())  # no CRF in these runs
            data.append(
                {
                    "system": system,
                    "variant": variant,
                    **{k: v.as_json() for k, v in stats.items()},
                }
            )
            label = VARIANTS[variant].label if variant in VARIANTS else variant
            body.append([label, *(stats[k].text(1) for k in keys)])
        lines += [
            f"### Time per frame ({system})",
            "",
            "Mean wall milliseconds per frame over every run of the variant (all models and "
            "sequences; the SLAM runs' timing_ms). Segmentation includes the dense CRF; it runs "
            "in the prefetch threads, in parallel with tracking, so it can exceed the total.",
            "",
            *_md(["variant", "segmentation [ms]", "CRF [ms]", "total [ms]", "frames/s"], body),
            "",
        ]
    return data, lines


BASELINES = ("none", "geometry", "oracle")


def table_baselines(rows, layout: Layout) -> tuple[list[dict[str, Any]], list[str]]:
    data: list[dict[str, Any]] = []
    lines: list[str] = []
    shown = [v for v in BASELINES if v in layout.variants]
    if not shown:
        return data, []
    for system in layout.systems:
        body = []
        for sequence in layout.sequences:
            cells = [sequence]
            for variant in shown:
                s = stat(_slam_rows(rows, system, sequence, variant), "ate_rmse")
                cells.append(s.text(4))
                data.append(
                    {"system": system, "sequence": sequence, "variant": variant, **s.as_json()}
                )
            body.append(cells)
        lines += [
            f"### Baselines: ATE RMSE [m] without a trained segmenter ({system})",
            "",
            *_md(["sequence", *(VARIANTS[v].label for v in shown)], body),
            "",
        ]
    return data, lines


def downstream_ratio(none: float | None, model: float | None, oracle: float | None) -> float | None:
    """``(none − model) / (none − oracle)``; None when a value is missing or the oracle is no
    better than no filter (the ratio is then meaningless)."""
    if none is None or model is None or oracle is None or none - oracle <= 0:
        return None
    return (none - model) / (none - oracle)


RATIO_FILTERS = ("semantic", "semantic_geometry")
"""The filters of the downstream ratio tables (each when its SLAM runs were made)."""


def table_ratio(
    rows, layout: Layout
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[str]]:
    """The downstream ratio of every model filter per seed, the paired differences to
    source-only, and their markdown."""
    data: list[dict[str, Any]] = []
    paired_rows: list[dict[str, Any]] = []
    needed = {"none", "oracle", "semantic"}
    if not needed <= set(layout.variants):
        return (
            data,
            paired_rows,
            [
                "### Downstream ratio",
                "",
                "Not computed: needs the variants none, oracle and semantic.",
                "",
            ],
        )
    lines = [
        "### Downstream ratio (ATE_none − ATE_model) / (ATE_none − ATE_oracle)",
        "",
        "Per sequence and seed, for each model filter (the trained models, T0's AdaBN models "
        "and the target oracle, which used target labels): 1 = as good as ground-truth masks, "
        "0 = no better than no filter; — = a run failed, was not made, or the oracle was no "
        "better than no filter. Median and mean ± s.d. over the seeds. Each model's row "
        "\"− source_only\": its ratio minus source-only's, paired by seed (every seed's "
        "difference, on how many seeds it is positive, and the mean with its 95% Student-t "
        "interval over the seeds: an interval above 0 excludes no gain).",
        "",
    ]
    # T0's AdaBN models and the target oracle too: the baseline any method must beat, and how
    # close a model trained on target labels comes to the ground-truth masks
    configs = list(
        dict.fromkeys(
            c
            for c in (
                layout.source_only,
                *layout.adabn,
                *layout.adapted,
                *layout.methods,
                layout.oracle,
            )
            if c
        )
    )
    filters = [f for f in RATIO_FILTERS if f in layout.variants]
    for system, variant in ((s, f) for s in layout.systems for f in filters):
        body = []
        per_sequence: dict[tuple[str, str], list[float]] = {}
        baselines = {
            sequence: (
                _one(_slam_rows(rows, system, sequence, "none")),
                _one(_slam_rows(rows, system, sequence, "oracle")),
            )
            for sequence in layout.sequences
        }
        for config in configs:
            # an AdaBN model has no training of its own: the seeds of its SLAM runs
            seeds = [r["seed"] for r in _select(rows, kind="train", config=config)] or sorted(
                {r["seed"] for r in _select(rows, kind="slam", config=config)}
            )
            if not any(_slam_rows(rows, system, s, variant, config) for s in layout.sequences):
                continue  # this filter was not run with this model
            for seed in seeds:
                cells = [config, str(seed)]
                for sequence in layout.sequences:
                    none_, oracle = baselines[sequence]
                    runs = [
                        r
                        for r in _slam_rows(rows, system, sequence, variant, config)
                        if r["seed"] == seed
                    ]
                    value = downstream_ratio(none_, _one(runs), oracle)
                    data.append(
                        {
                            "system": system,
                            "filter": variant,
                            "config": config,
                            "seed": seed,
                            "sequence": sequence,
                            "ratio": value,
                        }
                    )
                    if value is not None:
                        per_sequence.setdefault((config, sequence), []).append(value)
                    cells.append("—" if value is None else f"{value:.3f}")
                body.append(cells)
            values = [per_sequence.get((config, s), []) for s in layout.sequences]
            body.append(
                [config, "median", *(f"{statistics.median(v):.3f}" if v else "—" for v in values)]
            )
            body.append([config, "mean ± s.d.", *(Stat(tuple(v)).text(3) for v in values)])
            so = layout.source_only
            if (
                config != so
                and so is not None
                and any(
                    _ratios(data, system, variant, so, sequence) for sequence in layout.sequences
                )
            ):
                cells = [config, f"− {layout.source_only}"]
                for sequence in layout.sequences:
                    mine = _ratios(data, system, variant, config, sequence)
                    base = _ratios(data, system, variant, layout.source_only, sequence)
                    diffs = [mine[k] - base[k] for k in sorted(mine) if k in base]
                    paired = paired_interval(diffs)
                    paired_rows.append({"system": system, "filter": variant, "config": config,
                                        "sequence": sequence, **paired})  # fmt: skip
                    cells.append(paired_text(paired))
                body.append(cells)
        if not body:  # no model was run with this filter (e.g. ORB-SLAM3 + geometry)
            continue
        lines += [
            f"#### {system}, {variant.replace('_', '+')}",
            "",
            *_md(["configuration", "seed", *layout.sequences], body),
            "",
        ]
    return data, paired_rows, lines


def _ratios(data: list[dict[str, Any]], system: str, variant: str, config: str,
            sequence: str) -> dict[int, float]:  # fmt: skip
    """Seed -> downstream ratio of one model filter on one sequence (from ``table_ratio``'s
    rows so far)."""
    return {
        d["seed"]: d["ratio"]
        for d in data
        if d.get("ratio") is not None
        and (d["system"], d["filter"], d["config"], d["sequence"])
        == (system, variant, config, sequence)
    }


def paired_interval(diffs: Sequence[float], level: float = 0.95) -> dict[str, Any]:
    """Paired differences: each value, how many are positive, their mean and its Student-t
    interval at ``level`` (None below two values)."""
    out: dict[str, Any] = {"values": list(diffs), "positive": sum(d > 0 for d in diffs),
                           "n": len(diffs), "mean": None, "interval": None}  # fmt: skip
    if diffs:
        out["mean"] = statistics.fmean(diffs)
    if len(diffs) >= 2:
        from scipy.stats import t

        half = t.ppf(0.5 + level / 2, len(diffs) - 1) * statistics.stdev(diffs) / len(diffs) ** 0.5
        out["interval"] = [out["mean"] - half, out["mean"] + half]
    return out


def paired_text(paired: Mapping[str, Any]) -> str:
    """``+0.12 / +0.30 (2/2 > 0), mean +0.21 [-0.93, +1.35]`` of a :func:`paired_interval`."""
    if not paired["n"]:
        return "—"
    each = " / ".join(f"{d:+.2f}" for d in paired["values"])
    text = f"{each} ({paired['positive']}/{paired['n']} > 0)"
    if paired["interval"] is not None:
        lo, hi = paired["interval"]
        text += f", mean {paired['mean']:+.2f} [{lo:+.2f}, {hi:+.2f}]"
    return text


def _one(rows: Sequence[Mapping[str, Any]]) -> float | None:
    """The mean ATE RMSE of the successful runs among ``rows`` (None if none)."""
    return stat(rows, "ate_rmse").mean


def table_failures(rows) -> tuple[list[dict[str, Any]], list[str]]:
    bad = [r for r in rows if r["status"] != "ok"]
    data = [{"id": r["id"], "status": r["status"], "reason": r.get("reason") or ""} for r in bad]
    seen: set[str] = set()
    body = []
    for r in bad:  # segeval jobs have one row per sequence: list each job once
        if r["id"] in seen:
            continue
        seen.add(r["id"])
        body.append([f"`{r['id']}`", r["status"], (r.get("reason") or "").replace("|", "\\|")])
    lines = ["### Failures", ""]
    if not body:
        return data, [*lines, "Every job succeeded.", ""]
    counts = {s: len({r["id"] for r in bad if r["status"] == s}) for s in STATUSES[1:]}
    lines += [
        ", ".join(f"{n} {s}" for s, n in counts.items() if n) + " (blocked = an earlier job "
        "it needs failed; missing = the job left no result: killed or interrupted).",
        "",
    ]
    return data, [*lines, *_md(["job", "status", "reason"], body), ""]


def compute(
    rows: Sequence[Mapping[str, Any]],
    n_layers: int | None,
    layout: Layout | None = None,
    policy: str = "last",
) -> tuple[dict[str, Any], str]:
    """Every table: ``(tables.json content, tables.md text)``; ``policy``: the trainings'
    checkpoint policy (``train.checkpoint``: T0 marks the rows it selected with target labels)."""
    layout = layout or layout_from_rows(rows, n_layers)
    t0, t0_md = table_t0(rows, layout, policy)
    t1, t1_md = table_t1(rows, layout)
    t2, t2_md = table_t2(rows, layout)
    methods, methods_md = table_methods(rows, layout)
    t2["by_method"] = methods
    t3, t3_md = table_t3(rows, layout)
    crf, crf_md = table_crf(rows, layout)
    base, base_md = table_baselines(rows, layout)
    ratio, paired, ratio_md = table_ratio(rows, layout)
    timing, timing_md = table_timing(rows, layout)
    failures, failures_md = table_failures(rows)
    data = {
        "layout": {
            "configs": list(layout.configs),
            "sequences": list(layout.sequences),
            "systems": list(layout.systems),
            "variants": list(layout.variants),
            "source_only": layout.source_only,
            "adapted": list(layout.adapted),
            "methods": list(layout.methods),
            "crf_configs": list(layout.crf_configs),
            "adabn": list(layout.adabn),
            "oracle": layout.oracle,
            "n_layers": n_layers,
        },
        "T0": t0,
        "T1": t1,
        "T2": t2,
        "T3": t3,
        "crf": crf,
        "baselines": base,
        "downstream_ratio": ratio,
        "downstream_ratio_paired": paired,
        "timing": timing,
        "failures": failures,
    }
    text = "\n".join(
        [
            *t0_md,
            *t1_md,
            *t2_md,
            *methods_md,
            *t3_md,
            *crf_md,
            *base_md,
            *ratio_md,
            *timing_md,
            *failures_md,
        ]
    )
    return data, text


# ---------------------------------------------------------------------------------- plots


def _bars(
    ax: Any, groups: Sequence[str], series: Sequence[tuple[str, Sequence[Stat]]], scale: float = 1.0
) -> None:
    """Grouped bars of the means with s.d. error bars; failed / empty cells show no bar."""
    import numpy as np

    width = 0.8 / max(len(series), 1)
    x = np.arange(len(groups))
    for k, (label, stats) in enumerate(series):
        means = [scale * s.mean if s.mean is not None else np.nan for s in stats]
        errs = [scale * s.sd if s.sd is not None else 0.0 for s in stats]
        ax.bar(
            x + (k - (len(series) - 1) / 2) * width, means, width, yerr=errs, capsize=3, label=label
        )
    ax.set_xticks(x, groups, rotation=15, fontsize=8)


def write_plots(out: Path, rows: Sequence[Mapping[str, Any]], layout: Layout) -> list[Path]:
    """``t1_miou.png``, ``t1_iou_per_class.png`` and ``ate_per_sequence.png`` in ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []

    def save(fig: Any, name: str) -> None:
        path = out / name
        tmp = out / f".{name}.tmp.png"
        fig.tight_layout()
        fig.savefig(tmp, dpi=110)
        plt.close(fig)
        tmp.replace(path)
        written.append(path)

    configs = list(layout.configs)
    fig, ax = plt.subplots(figsize=(max(5.0, 1.1 * len(configs)), 3.4))
    _bars(
        ax,
        configs,
        [("target mIoU", [stat(_seg_rows(rows, c, ALL_SEQUENCES), "mIoU") for c in configs])],
    )
    ax.set_ylabel("mIoU")
    ax.set_title("T1: target mIoU by configuration (mean ± s.d. over seeds)")
    save(fig, "t1_miou.png")

    fig, ax = plt.subplots(figsize=(max(6.0, 1.4 * len(CLASS_NAMES) + 2) + 2.0, 3.6))
    _bars(
        ax,
        list(CLASS_NAMES),
        [
            (c, [stat(_seg_rows(rows, c, ALL_SEQUENCES), f"IoU_{name}") for name in CLASS_NAMES])
            for c in configs
        ],
    )
    ax.set_ylabel("IoU")
    ax.set_title("Per-class IoU on the evaluation sequences (mean ± s.d. over seeds)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    save(fig, "t1_iou_per_class.png")

    series_spec: list[tuple[str, str, str | None]] = [
        (VARIANTS[v].label, v, None) for v in BASELINES if v in layout.variants
    ]
    for config in (layout.source_only, *layout.adapted):
        if config is None:
            continue
        for v in VARIANTS:
            if VARIANTS[v].segmenter == "model" and v in layout.variants:
                series_spec.append((f"{config} {VARIANTS[v].label}", v, config))
    systems = list(layout.systems) or ["harness"]
    fig, axes = plt.subplots(
        len(systems),
        1,
        figsize=(max(7.0, 2.2 * len(layout.sequences)) + 3.0, 3.6 * len(systems)),
        squeeze=False,
    )
    for ax, system in zip(axes[:, 0], systems, strict=True):
        _bars(
            ax,
            list(layout.sequences),
            [
                (
                    label,
                    [stat(_slam_rows(rows, system, s, v, c), "ate_rmse") for s in layout.sequences],
                )
                for label, v, c in series_spec
            ],
            scale=100.0,
        )
        ax.set_ylabel("ATE RMSE [cm]")
        ax.set_title(f"ATE per sequence ({system}; mean ± s.d. over seeds)")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    save(fig, "ate_per_sequence.png")
    return written


def write_tables(
    out: Path,
    rows: Sequence[Mapping[str, Any]],
    n_layers: int | None,
    header: Sequence[str] = (),
    layout: Layout | None = None,
    plots: bool = True,
    policy: str = "last",
) -> dict[str, Any]:
    """``tables.md``, ``tables.json`` and the plots (under ``plots/``) in ``out``."""
    layout = layout or layout_from_rows(rows, n_layers)
    data, text = compute(rows, n_layers, layout, policy)
    images = write_plots(out / "plots", rows, layout) if plots else []
    md = [*header, text]
    if images:
        md += ["### Plots", "", *(f"![{p.stem}](plots/{p.name})" for p in images), ""]
    write_text_atomic(out / "tables.md", "\n".join(md))
    write_text_atomic(out / "tables.json", json.dumps(data, indent=2) + "\n")
    return data

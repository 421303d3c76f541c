"""T0, the standard UDA table: source-only, AdaBN, each method and the target oracle, with
closure paired by seed (the package docstring)."""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from uss_slam.pipelines.runs import USES_TARGET_LABELS

from ..grid import ADABN, TARGET_LABEL_USES
from .layout import DAGGER_NOTE, Layout, select, slam_rows
from .markdown import LABELS, md_table, value_text
from .runs_csv import RATES, SOURCE_VAL
from .stats import (
    MDE_FORMULA,
    SeedValues,
    is_defined,
    mde,
    paired_closure,
    paired_interval,
    paired_text,
    stat,
)

T0_SEG = ("mIoU", "IoU_person")
T0_FRAMES = tuple(f"person_{r}" for r in RATES)


def seed_means(
    rows: Sequence[Mapping[str, Any]], config: str, key: str, sequences: Sequence[str]
) -> SeedValues:
    """Per seed, the mean of column ``key`` over the segmentation rows of ``config`` on
    ``sequences`` (no CRF) where it is defined; a seed whose evaluation has no result counts as
    failed, one without a defined value as undefined."""
    by_seed: dict[int, list[Mapping[str, Any]]] = {}
    for r in select(rows, kind="segeval", config=config):
        if r.get("sequence") in sequences and not r.get("crf") and r.get("seed") is not None:
            by_seed.setdefault(int(r["seed"]), []).append(r)
    values: dict[int, float] = {}
    failed = undefined = 0
    for seed in sorted(by_seed):
        seed_rows = by_seed[seed]
        if any(r["status"] != "ok" for r in seed_rows):
            failed += 1
            continue
        defined = [float(r[key]) for r in seed_rows if is_defined(r.get(key))]
        if defined:
            values[seed] = statistics.fmean(defined)
        else:
            undefined += 1
    return SeedValues(values, failed, undefined)


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


def target_labels(role: str, policy: str, uses: Sequence[str] = ()) -> str:
    """What target labels a T0 row used: the oracle's training, method settings chosen on
    labelled target validation frames (``uses``: its rows' ``target_labels``), and the
    checkpoint selection of a policy that reads them (``train.checkpoint=best_target_val``)."""
    used = {*uses, *(["training"] if role == "oracle" else [])}
    used |= {"checkpoint selection"} if policy in USES_TARGET_LABELS else set()
    return ", ".join(u for u in TARGET_LABEL_USES if u in used) or "none"


def labels_line(used: Sequence[tuple[str, str]]) -> str:
    """T0's header line: ``target labels used: none``, or each † row and what it used them
    for (``used``: ``(config, target_labels text)`` of the rows that used them)."""
    if not used:
        return "target labels used: none"
    return "target labels used: " + "; ".join(f"{c} ({what})" for c, what in used)


def paired_points(row: SeedValues, reference: SeedValues) -> dict[str, Any]:
    """``row − reference`` in points (100 × the difference), paired by seed over the seeds
    both have (:func:`~.stats.paired_interval`: values, interval, MDE)."""
    seeds = [s for s in sorted(row.values) if s in reference.values]
    return paired_interval([100.0 * (row.values[s] - reference.values[s]) for s in seeds])


def t0_differences(
    order: Sequence[tuple[str, str]],
    cells: Mapping[str, Mapping[str, SeedValues]],
    names: Mapping[str, str],
) -> tuple[list[dict[str, Any]], list[list[str]]]:
    """Each T0 row against source-only and against source-only's AdaBN (the baseline any
    method must beat), target mIoU and person IoU in points, paired by seed with their 95%
    interval and MDE: ``(json rows, table body)``."""
    so = next(c for c, role in order if role == "source-only")
    adabn = next((c for c, role in order if role == "AdaBN" and not c.endswith(f"_{ADABN}")), None)
    data: list[dict[str, Any]] = []
    body: list[list[str]] = []
    for config, _ in order:
        for reference in (so, adabn):
            if reference is None or config in (so, reference):
                continue
            entry: dict[str, Any] = {"config": config, "against": reference}
            cells_ = [names[config], f"− {names[reference]}"]
            for k in T0_SEG:
                paired = paired_points(cells[config][k], cells[reference][k])
                entry[k] = paired
                cells_.append(paired_text(paired, with_mde=True))
            data.append(entry)
            body.append(cells_)
    return data, body


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
    body, per_seed, frames, used = [], [], [], []
    names: dict[str, str] = {}
    for config, role in order:
        labels = target_labels(role, policy, layout.target_labels.get(config, ()))
        name = names[config] = config + (" †" if labels != "none" else "")
        used += [(config, labels)] if labels != "none" else []
        c = cells[config]
        mdes = {k: mde(c[f"closure_{k}"].stat.sd, c[f"closure_{k}"].stat.n) for k in T0_SEG}
        ate = {
            (system, seq): stat(slam_rows(rows, system, seq, "semantic", config), "ate_rmse")
            for system in systems
            for seq in sequences
        }
        data["rows"].append(
            {
                "config": config,
                "role": role,
                "target_labels": labels,
                **{k: v.as_json() for k, v in c.items()},
                **{f"closure_{k}_mde": v for k, v in mdes.items()},
                "ate_rmse": [
                    {"system": system, "sequence": seq, **s.as_json(), "se": s.se}
                    for (system, seq), s in ate.items()
                ],
            }
        )
        body.append(
            [
                name,
                labels,
                *(c[k].stat.text(3, "se") for k in main),
                *(value_text(mdes[k]) for k in T0_SEG),
            ]
        )
        frames.append(
            [
                name,
                *(c[k].stat.text(3, "se") for k in T0_FRAMES),
                *(s.text(4, "se") for s in ate.values()),
            ]
        )
        seeds = sorted(
            {int(r["seed"]) for r in select(rows, config=config) if r.get("seed") is not None}
        )
        for seed in seeds:
            per_seed.append([name, str(seed), *(value_text(c[k].values.get(seed)) for k in main)])
    header = [
        "row",
        "target labels used",
        "source val mIoU (in domain)",
        "target mIoU",
        "person IoU",
        "closure (mIoU)",
        "closure (person IoU)",
    ]
    mde_header = ["MDE closure (mIoU)", "MDE closure (person IoU)"]
    data["differences"], differences = t0_differences(order, cells, names)
    dagger = [DAGGER_NOTE, ""] if used else []
    lines = [
        title,
        "",
        labels_line(used),
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
        "table has every seed's value. † = target labels used (column 2): training = the "
        "oracle's (a reference, not a method); settings = method settings chosen on labelled "
        "target validation frames (the shift preset's, grid.method_overrides: null); checkpoint "
        "selection = train.checkpoint=best_target_val. MDE closure: the "
        "smallest mean closure the seeds can tell from 0 (footnote).",
        "",
        *md_table([*header, *mde_header], body),
        "",
        *dagger,
        MDE_FORMULA + ".",
        "",
        *(
            [
                "#### T0 paired differences",
                "",
                "Each row minus source-only and minus AdaBN (source-only's checkpoint with "
                "target statistics: the baseline any method must beat), in points (100 × the "
                "difference), paired by seed: every seed's difference, on how many it is "
                "positive, the mean with its 95% Student-t interval, and the MDE (footnote).",
                "",
                *md_table(["row", "against", "target mIoU", "person IoU"], differences),
                "",
                *dagger,
                MDE_FORMULA + ".",
                "",
            ]
            if differences
            else []
        ),
        "#### T0 per seed",
        "",
        *md_table(["row", "seed", *header[2:]], per_seed),
        "",
        *dagger,
        "#### T0 person masks and SLAM",
        "",
        "Person-mask frame metrics (as in T2; mean over the evaluation sequences) and ATE RMSE "
        "[m] with the semantic filter; mean ± standard error over seeds.",
        "",
        *md_table(
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
        *dagger,
    ]
    return data, lines

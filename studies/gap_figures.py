"""Every primary figure of the real-regime study, recomputed from its committed files.

Reads the per-seed, per-render confusion matrices that ``studies/gap_study.py score`` wrote
(one CSV row per model and render: classes background, person, chair, monitor; pixels) and,
when given, the discriminators' accuracy over training (``gap_study.py dacc``), and prints
(or writes with ``--markdown``) the tables the protocol fixed (``docs/results/protocol.md``,
"the real regime"):

- per row: person IoU and mIoU in points, per render the mean over the training seeds, then the
  mean over renders with its 95% Student-t interval over renders;
- per comparison A − B: the per-render difference of the seed means, paired across renders
  (mean, 95% interval, minimum detectable effect, renders above 0), and the variance split of
  the per-(render, seed) differences (two-way ANOVA, renders × seeds, one value per cell):
  render, seed and residual components;
- the closure (A − source-only) / (oracle − source-only), its 95% interval by a bootstrap over
  renders (2000 resamples, seed 0), and the headroom oracle − continued source-only;
- exploratory: each comparison's per-render differences grouped by preset;
- per adversarial row: each seed's discriminator accuracy per head (the largest 25-iteration
  block mean and the mean of the last quarter), and the runs whose discriminator never left
  chance (every block mean of both heads inside [0.4, 0.6]) marked ``D at chance``.

::

    python studies/gap_figures.py docs/results/gap_main/confusion.csv \\
        [--dacc docs/results/gap_main/d_acc.csv] [--markdown FILE] [--role eval|pilot] \\
        [--power RENDERS SEEDS]

``--power 24 8`` adds, per comparison, the minimum detectable effect at 24 renders × 8 seeds from
this file's variance components (the pilot's power computation).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import iou_per_class
from uss_slam.pipelines.experiments.tables.stats import paired_interval

N = len(CLASS_NAMES)
PERSON = CLASS_NAMES.index("person")
SOURCE_ONLY = "source_only_bntrained"
ORACLE = "oracle"
ROWS = {
    "init": "the init as is",
    "init_adabn": "the init + AdaBN (no training)",
    "source_only_bntrained": "continued source-only (`trained` BatchNorm)",
    "source_only_bnreference": "continued source-only (`reference` BatchNorm)",
    "adabn_bntrained": "AdaBN (of continued source-only, `trained`)",
    "adabn_bnreference": "AdaBN of source-only `reference` (exploratory)",
    "adaptsegnet_n5_bnreference": "AdaptSegNet (`reference` BatchNorm)",
    "advent_n5_bnreference": "ADVENT (`reference` BatchNorm)",
    "fda_bntrained": "FDA (`trained` BatchNorm, published defaults)",
    "fda_bntrained_adabn": "FDA + AdaBN (exploratory)",
    "oracle": "target oracle †",
}
"""The study's rows, in table order (labels as the tables print them)."""
COMPARISONS = (
    ("headroom", "oracle", SOURCE_ONLY),
    ("H1 AdaBN", "adabn_bntrained", SOURCE_ONLY),
    ("H1 AdaptSegNet", "adaptsegnet_n5_bnreference", SOURCE_ONLY),
    (
        "H2 adversarial term (BatchNorm equal)",
        "adaptsegnet_n5_bnreference",
        "source_only_bnreference",
    ),
    ("H2' ADVENT term (BatchNorm equal)", "advent_n5_bnreference", "source_only_bnreference"),
    ("H5 FDA", "fda_bntrained", SOURCE_ONLY),
    ("exploratory: FDA − AdaBN", "fda_bntrained", "adabn_bntrained"),
    ("exploratory: FDA + AdaBN − FDA", "fda_bntrained_adabn", "fda_bntrained"),
    ("exploratory: AdaptSegNet − AdaBN", "adaptsegnet_n5_bnreference", "adabn_bntrained"),
    ("exploratory: continued source-only − init", SOURCE_ONLY, "init"),
    ("exploratory: init + AdaBN − init", "init_adabn", "init"),
    ("exploratory: BatchNorm mode (reference − trained)", "source_only_bnreference", SOURCE_ONLY),
)
"""(label, row A, row B) of every paired comparison, as the protocol lists them."""
CHANCE = (0.4, 0.6)


def read_scores(
    paths: Path | list[Path], role: str | None
) -> dict[str, dict[str, dict[str, dict[str, float]]]]:
    """``{row: {render: {seed: {"person": pts, "mIoU": pts}}}}`` from confusion CSVs (one
    matrix per row, render and seed over all of them: a repeat is one line naming both places)."""
    scores: dict = defaultdict(lambda: defaultdict(dict))
    where: dict[tuple[str, str, str], str] = {}
    for path in [paths] if isinstance(paths, Path) else paths:
        with open(path, newline="") as f:
            for line, r in enumerate(csv.DictReader(f), start=2):
                if role and r["role"] != role:
                    continue
                matrix = np.array([[int(r[f"c{t}{p}"]) for p in range(N)] for t in range(N)])
                iou = iou_per_class(matrix)
                render = f"{r['preset']}_{r['render_seed']}"
                key = (r["row"], render, r["seed"])
                if key in where:
                    sys.exit(f"gap_figures: error: {path}:{line}: {r['model']} on {render} is "
                             f"scored already at {where[key]}")  # fmt: skip
                where[key] = f"{path}:{line}"
                scores[r["row"]][render][r["seed"]] = {
                    "person": 100.0 * float(iou[PERSON]),
                    "mIoU": 100.0 * float(np.nanmean(iou)),
                }
    if not scores:
        names = ", ".join(map(str, [paths] if isinstance(paths, Path) else paths))
        sys.exit(f"gap_figures: error: {names}: no rows" + (f" with role {role}" if role else ""))
    return scores


def render_means(by_render: dict[str, dict[str, dict[str, float]]], key: str) -> dict[str, float]:
    """Per render, the mean over its seeds."""
    return {r: statistics.fmean(v[key] for v in seeds.values()) for r, seeds in by_render.items()}


def interval_text(p: dict, mde: bool = True) -> str:
    if not p["n"]:
        return "—"
    if p["interval"] is None:
        return f"{p['mean']:+.1f} (n={p['n']})"
    lo, hi = p["interval"]
    text = f"{p['mean']:+.1f} [{lo:+.1f}, {hi:+.1f}]"
    if mde:
        text += f", MDE {p['mde']:.1f}, {p['positive']}/{p['n']} renders > 0"
    return text


def variance_split(a: dict, b: dict, key: str) -> dict[str, float] | None:
    """Components of the per-(render, seed) differences ``a − b`` (renders × common seeds;
    rows without seeds pair every seed of the other with their one value)."""
    renders = sorted(set(a) & set(b))
    seeds = sorted(set.intersection(*(set(a[r]) | set(b[r]) for r in renders))) if renders else []
    seeds = [s for s in seeds if s]
    if len(renders) < 2 or len(seeds) < 2:
        return None

    def value(row: dict, r: str, s: str) -> float:
        cell = row[r].get(s) or row[r].get("")
        return cell[key]

    d = np.array([[value(a, r, s) - value(b, r, s) for s in seeds] for r in renders])
    nr, ns = d.shape
    grand = d.mean()
    ms_r = ns * ((d.mean(1) - grand) ** 2).sum() / (nr - 1)
    ms_s = nr * ((d.mean(0) - grand) ** 2).sum() / (ns - 1)
    resid = d - d.mean(1, keepdims=True) - d.mean(0, keepdims=True) + grand
    ms_e = (resid**2).sum() / ((nr - 1) * (ns - 1))
    return {"render": max(0.0, (ms_r - ms_e) / ns), "seed": max(0.0, (ms_s - ms_e) / nr),
            "residual": float(ms_e), "renders": nr, "seeds": ns}  # fmt: skip


def projected_mde(split: dict[str, float], renders: int, seeds: int) -> float:
    """MDE (points) of a comparison paired across ``renders`` renders, each the mean of
    ``seeds`` seeds, from variance components: s² = render + (seed + residual) / seeds."""
    from scipy.stats import t

    sd = (split["render"] + (split["seed"] + split["residual"]) / seeds) ** 0.5
    return float((t.ppf(0.975, renders - 1) + t.ppf(0.80, renders - 1)) * sd / renders**0.5)


def power_lines(scores: dict, renders: int, seeds: int) -> list[str]:
    """Per comparison and figure: the variance components and the MDE they give at
    ``renders`` renders × ``seeds`` seeds."""
    out = [f"Power at {renders} renders × {seeds} seeds (MDE, points, from these variance "
           "components):", "", "| comparison | person IoU MDE | mIoU MDE |", "|---|---|---|"]  # fmt: skip
    for label, row, against in COMPARISONS:
        if row not in scores or against not in scores:
            continue
        cells = []
        for key in ("person", "mIoU"):
            split = variance_split(scores[row], scores[against], key)
            cells.append("—" if split is None else f"{projected_mde(split, renders, seeds):.2f}")
        out.append(f"| {label}: {row} − {against} | {cells[0]} | {cells[1]} |")
    return out


def paired(scores: dict, row: str, against: str, key: str) -> dict:
    a, b = render_means(scores[row], key), render_means(scores[against], key)
    renders = sorted(set(a) & set(b))
    return paired_interval([a[r] - b[r] for r in renders])


def preset_lines(scores: dict) -> list[str]:
    """Exploratory: each comparison's per-render person-IoU differences grouped by preset (the
    render name's prefix), with the preset's mean."""
    out = ["Per preset (exploratory): person-IoU difference of each render, and the mean:", "",
           "| comparison | preset | mean | renders |", "|---|---|---|---|"]  # fmt: skip
    for _label, row, against in COMPARISONS:
        if row not in scores or against not in scores:
            continue
        a, b = render_means(scores[row], "person"), render_means(scores[against], "person")
        by: dict[str, list[float]] = defaultdict(list)
        for r in sorted(set(a) & set(b), key=lambda r: int(r.rsplit("_", 1)[1])):
            by[r.rsplit("_", 1)[0]].append(a[r] - b[r])
        for preset, diffs in sorted(by.items()):
            each = " ".join(f"{d:+.0f}" for d in diffs)
            out.append(
                f"| {row} − {against} | {preset} | {statistics.fmean(diffs):+.1f} | {each} |"
            )
    return out


def closure(scores: dict, row: str, key: str = "person") -> tuple[float, float, float] | None:
    """(closure, 2.5%, 97.5%) of ``row`` over renders, bootstrap (2000 resamples, seed 0)."""
    if any(r not in scores for r in (row, SOURCE_ONLY, ORACLE)):
        return None
    m, s, o = (render_means(scores[x], key) for x in (row, SOURCE_ONLY, ORACLE))
    renders = sorted(set(m) & set(s) & set(o))
    gain = np.array([m[r] - s[r] for r in renders])
    gap = np.array([o[r] - s[r] for r in renders])
    rng = np.random.default_rng(0)
    picks = rng.integers(0, len(renders), (2000, len(renders)))
    boot = gain[picks].mean(1) / gap[picks].mean(1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return float(gain.mean() / gap.mean()), float(lo), float(hi)


def read_dacc(path: Path) -> dict[str, dict[str, dict[str, list[float]]]]:
    """``{row: {seed: {head: [block means]}}}``."""
    out: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            out[r["row"]][r["seed"]][r["head"]].append(float(r["d_acc"]))
    return out


def at_chance(heads: dict[str, list[float]]) -> bool:
    """Every block mean of every head inside :data:`CHANCE`."""
    values = [v for blocks in heads.values() for v in blocks]
    return bool(values) and all(CHANCE[0] <= v <= CHANCE[1] for v in values)


def dacc_lines(dacc: dict) -> tuple[list[str], dict[str, str]]:
    """The discriminator table and, per row, its ``D at chance k/n`` mark."""
    lines = ["| row | seed | main: max / last quarter | aux: max / last quarter | |",
             "|---|---|---|---|---|"]  # fmt: skip
    marks = {}
    for row, seeds in sorted(dacc.items()):
        chance = 0
        for seed, heads in sorted(seeds.items(), key=lambda x: int(x[0] or 0)):
            cells = []
            for head in ("main", "aux"):
                blocks = heads.get(head, [])
                tail = blocks[-max(1, len(blocks) // 4) :] if blocks else []
                cells.append(f"{max(blocks):.3f} / {statistics.fmean(tail):.3f}" if blocks else "—")
            flag = at_chance(heads)
            chance += flag
            lines.append(
                f"| {row} | {seed} | {cells[0]} | {cells[1]} | {'D at chance' if flag else ''} |"
            )
        if chance:
            marks[row] = f"D at chance on {chance}/{len(seeds)} seeds"
    return lines, marks


def tables(scores: dict, dacc: dict | None) -> list[str]:
    marks: dict[str, str] = {}
    dlines: list[str] = []
    if dacc is not None:
        dlines, marks = dacc_lines(dacc)
    renders = sorted({r for row in scores.values() for r in row})
    seeds = sorted({s for row in scores.values() for r in row.values() for s in r if s}, key=int)
    out = [f"Renders: {len(renders)} ({', '.join(renders)}); training seeds: {', '.join(seeds)}.",
           "", "| row | person IoU | mIoU | |", "|---|---|---|---|"]  # fmt: skip
    for row in [r for r in ROWS if r in scores] + sorted(set(scores) - set(ROWS)):
        cells = []
        for key in ("person", "mIoU"):
            values = list(render_means(scores[row], key).values())
            p = paired_interval(values)
            lo, hi = p["interval"] or (p["mean"], p["mean"])
            cells.append(f"{p['mean']:.1f} [{lo:.1f}, {hi:.1f}]")
        out.append(f"| {ROWS.get(row, row)} | {cells[0]} | {cells[1]} | {marks.get(row, '')} |")
    out += ["", "Paired across renders (per render the mean over seeds), points:", "",
            "| comparison | person IoU | mIoU | variance split of person IoU (render / seed / residual) |",
            "|---|---|---|---|"]  # fmt: skip
    for label, row, against in COMPARISONS:
        if row not in scores or against not in scores:
            continue
        split = variance_split(scores[row], scores[against], "person")
        split_text = "—" if split is None else (
            f"{split['render']:.1f} / {split['seed']:.1f} / {split['residual']:.1f} "
            f"({split['renders']} renders × {split['seeds']} seeds)")  # fmt: skip
        out.append(f"| {label}: {row} − {against} | "
                   f"{interval_text(paired(scores, row, against, 'person'))} | "
                   f"{interval_text(paired(scores, row, against, 'mIoU'))} | {split_text} |")  # fmt: skip
    out += ["", "Closure in person IoU, (row − continued source-only) / (oracle − continued "
            "source-only), bootstrap over renders:", ""]  # fmt: skip
    for row in ROWS:
        if row in (SOURCE_ONLY, ORACLE) or row not in scores:
            continue
        c = closure(scores, row)
        if c is not None:
            out.append(f"- {ROWS[row]}: {c[0]:.2f} [{c[1]:.2f}, {c[2]:.2f}]")
    out += ["", *preset_lines(scores)]
    if dlines:
        out += ["", "Discriminator accuracy per head (25-iteration block means; 0.5 = chance):", "",
                *dlines]  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("confusion", type=Path, nargs="+",
                        help="gap_study.py score's CSVs (one matrix per model and render)")  # fmt: skip
    parser.add_argument("--dacc", type=Path, help="gap_study.py dacc's CSV")
    parser.add_argument("--role", choices=("pilot", "eval"), help="keep only these rows")
    parser.add_argument("--markdown", type=Path, help="also write the tables to this file")
    parser.add_argument("--power", nargs=2, type=int, metavar=("RENDERS", "SEEDS"),
                        help="also the MDE of each comparison at this design")  # fmt: skip
    args = parser.parse_args(argv)
    for path in (*args.confusion, args.dacc):
        if path is not None and not path.is_file():
            sys.exit(f"gap_figures: error: {path}: no such file")
    scores = read_scores(args.confusion, args.role)
    lines = tables(scores, read_dacc(args.dacc) if args.dacc else None)
    if args.power:
        lines += ["", *power_lines(scores, *args.power)]
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if args.markdown:
        args.markdown.write_text(text)


if __name__ == "__main__":
    main()

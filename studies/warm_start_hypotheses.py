"""Do the pre-registered hypotheses of the warm-start design hold on the evaluation renders?

Reads one ``uss-experiments`` output folder (the main runs of ``docs/results/protocol.md``) and
prints the four hypotheses' primary comparisons, each as the paired difference over adaptation
seeds (every seed's value, the mean, its two-sided 95% Student-t interval and the minimum
detectable effect, as the tables print them), with the protocol's decision rule applied:

- H1: AdaBN − continued source-only (person IoU, then mIoU), one-sided reading (> 0);
- H2: AdaptSegNet (``reference`` BatchNorm) − source-only, one-sided (> 0);
- H3: AdaptSegNet (``reference``) − AdaBN, two-sided: decided when the interval excludes 0, or
  lies inside ± the MDE and the MDE is ≤ 3 points;
- H4: the downstream ratio with AdaBN's masks − with source-only's, per walking sequence and
  system, one-sided (> 0); the ratio is ``(ATE_none − ATE_model) / (ATE_none − ATE_oracle)``
  (1 = as good as ground-truth masks) and, as the protocol words it, ``ATE_model / ATE_none``.

Segmentation figures are pooled over the walking renders only (each sequence's confusion
matrix, summed); static_xyz is reported beside them as the control. Exploratory rows
(self-training, the oracle's closure) follow, labelled so. Reported in
``docs/results/README.md`` ("Warm start: the main runs").

Usage::

    python studies/warm_start_hypotheses.py OUT_DIR [--markdown FILE] [--seeds 0-7]

``--seeds`` keeps only those adaptation seeds (``0-7``, ``0,2,5`` or both mixed), e.g. to read a
16-seed folder on the 8 seeds of another run beside it; a seed that no model has is an error.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import statistics
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import iou_per_class
from uss_slam.pipelines.experiments.tables.stats import downstream_ratio, paired_interval

WALKING = ("walking_xyz", "walking_rpy", "walking_halfsphere")
CONTROL = "static_xyz"
PERSON = CLASS_NAMES.index("person")
ADAPTSEGNET = "adaptsegnet_n5_bnreference"
MODEL_ID = re.compile(r"^(?P<model>.+)_s(?P<seed>\d+)$")


def seg_scores(out: Path, sequences: tuple[str, ...]) -> dict[str, dict[int, dict[str, float]]]:
    """``{model: {seed: {"mIoU": points, "person": points}}}`` pooled over ``sequences``."""
    scores: dict[str, dict[int, dict[str, float]]] = defaultdict(dict)
    for result in sorted((out / "segeval").glob("*/result.json")):
        match = MODEL_ID.match(result.parent.name)
        if match is None:
            continue
        found = json.loads(result.read_text())["sequences"]
        missing = [s for s in sequences if s not in found or "confusion" not in found[s]]
        if missing:
            sys.exit(f"{result}: no confusion matrix for {', '.join(missing)}")
        matrix = sum(np.array(found[s]["confusion"], np.int64) for s in sequences)
        iou = iou_per_class(matrix)
        scores[match["model"]][int(match["seed"])] = {
            "mIoU": 100.0 * float(np.nanmean(iou)),
            "person": 100.0 * float(iou[PERSON]),
        }
    return scores


def parse_seeds(text: str) -> set[int]:
    """``"0-7"``, ``"0,2,5"`` or a mix (``"0-3,8"``) -> the set of seeds."""
    seeds: set[int] = set()
    for part in text.split(","):
        bounds = part.strip().split("-")
        if not all(b.strip().isdigit() for b in bounds) or len(bounds) > 2:
            raise argparse.ArgumentTypeError(
                f"expected seeds as 0-7, 0,2,5 or 0-3,8 (integers >= 0), got {text!r}"
            )
        lo, hi = int(bounds[0]), int(bounds[-1])
        if hi < lo:
            raise argparse.ArgumentTypeError(f"a range must go up, got {part.strip()!r}")
        seeds.update(range(lo, hi + 1))
    return seeds


def keep_seeds(scores: dict[str, dict[int, dict]], seeds: set[int]) -> dict[str, dict[int, dict]]:
    """``scores`` with only ``seeds`` (every model); a seed no model has exits with one line."""
    present = {s for by_seed in scores.values() for s in by_seed}
    missing = sorted(seeds - present)
    if missing:
        sys.exit(
            f"--seeds: no model has seed(s) {', '.join(map(str, missing))}; "
            f"the folder has {', '.join(map(str, sorted(present))) or 'none'}"
        )
    return {m: {s: v for s, v in by_seed.items() if s in seeds} for m, by_seed in scores.items()}


def paired(
    scores: dict[str, dict[int, dict[str, float]]], row: str, against: str, key: str
) -> dict:
    seeds = sorted(set(scores.get(row, {})) & set(scores.get(against, {})))
    return paired_interval([scores[row][s][key] - scores[against][s][key] for s in seeds])


def text(p: dict, digits: int = 2) -> str:
    if not p["n"]:
        return "—"
    if p["interval"] is None:
        return f"{p['mean']:+.{digits}f} (n={p['n']})"
    lo, hi = p["interval"]
    mde = "—" if p["mde"] is None else f"{p['mde']:.{digits}f}"
    return (
        f"{p['mean']:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}], MDE {mde}, "
        f"{p['positive']}/{p['n']} > 0"
    )


def one_sided(p: dict) -> str:
    if p["interval"] is None:
        return "undecided (fewer than 2 seeds)"
    return "holds (interval above 0)" if p["interval"][0] > 0 else "not shown (interval reaches 0)"


def two_sided(p: dict, bound: float = 3.0) -> str:
    if p["interval"] is None:
        return "undecided (fewer than 2 seeds)"
    lo, hi = p["interval"]
    if lo > 0 or hi < 0:
        return "decided: a difference (interval excludes 0)"
    mde = p["mde"]
    if mde is not None and mde <= bound and -mde <= lo and hi <= mde:
        return f"decided: equivalent within ± MDE {mde:.2f} ≤ {bound:g}"
    return "undecidable at this budget"


def slam_ratios(out: Path) -> dict[tuple[str, str], dict[str, dict[int, tuple[float, float]]]]:
    """``{(system, sequence): {model: {seed: (project ratio, ATE_model / ATE_none)}}}``."""
    rows = list(csv.DictReader((out / "runs.csv").open()))
    ate: dict[tuple[str, str, str], float] = {}
    per_model: dict[tuple[str, str], dict[str, dict[int, float]]] = defaultdict(
        lambda: defaultdict(dict)
    )
    for r in rows:
        if r["kind"] != "slam" or r["status"] != "ok" or not r["ate_rmse"]:
            continue
        parts = r["id"].split("/")  # slam/<system>/<sequence>/<variant>[/<model>]
        system, sequence, variant = parts[1], parts[2], parts[3]
        if len(parts) == 4:
            ate[(system, sequence, variant)] = float(r["ate_rmse"])
        elif variant == "semantic":
            match = MODEL_ID.match(parts[4])
            if match:
                per_model[(system, sequence)][match["model"]][int(match["seed"])] = float(
                    r["ate_rmse"]
                )
    out_: dict = {}
    for (system, sequence), models in per_model.items():
        none = ate.get((system, sequence, "none"))
        oracle = ate.get((system, sequence, "oracle"))
        if none is None:
            continue
        out_[(system, sequence)] = {
            model: {
                seed: (downstream_ratio(none, value, oracle), value / none)
                for seed, value in seeds.items()
            }
            for model, seeds in models.items()
        }
        out_[(system, sequence)]["_ate"] = {"none": none, "oracle": oracle}
    return out_


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the uss-experiments output folder")
    parser.add_argument("--markdown", type=Path, help="also write the report to this file")
    parser.add_argument(
        "--seeds",
        type=parse_seeds,
        help="only these adaptation seeds: 0-7, 0,2,5 or 0-3,8 (default: every seed found)",
    )
    args = parser.parse_args(argv)
    walking = seg_scores(args.out, WALKING)
    control = seg_scores(args.out, (CONTROL,))
    if args.seeds is not None:
        walking, control = keep_seeds(walking, args.seeds), keep_seeds(control, args.seeds)
    lines = [
        f"Output folder: {args.out}; segmentation pooled over {', '.join(WALKING)} "
        f"(paired differences in points; 95% Student-t interval; MDE at α 0.05, power 0.8)",
        "",
        "| hypothesis | comparison | figure | paired difference | reading |",
        "|---|---|---|---|---|",
    ]
    hypotheses = [
        ("H1", "adabn", "source_only", one_sided),
        ("H2", ADAPTSEGNET, "source_only", one_sided),
        ("H3", ADAPTSEGNET, "adabn", two_sided),
    ]
    for name, row, against, rule in hypotheses:
        for key, label in (("person", "person IoU"), ("mIoU", "mIoU")):
            p = paired(walking, row, against, key)
            primary = "" if key == "person" else " (secondary)"
            lines.append(
                f"| {name}{primary} | {row} − {against} | {label} | {text(p)} | {rule(p)} |"
            )
    lines += ["", "Exploratory (no hypothesis):", ""]
    lines += [
        "| comparison | figure | walking renders | static_xyz (control) |",
        "|---|---|---|---|",
    ]
    for row, against in (
        ("self_training", "source_only"),
        ("self_training", "adabn"),
        (ADAPTSEGNET, "source_only"),
        ("adabn", "source_only"),
        ("oracle", "source_only"),
    ):
        for key, label in (("person", "person IoU"), ("mIoU", "mIoU")):
            lines.append(
                f"| {row} − {against} | {label} | {text(paired(walking, row, against, key))} | "
                f"{text(paired(control, row, against, key))} |"
            )
    lines += ["", "Means over seeds (walking renders pooled), points:", ""]
    lines += ["| row | seeds | mIoU | person IoU | closure (person IoU) |", "|---|---|---|---|---|"]
    for row in ("source_only", "adabn", ADAPTSEGNET, "self_training", "oracle"):
        seeds = walking.get(row, {})
        if not seeds:
            continue
        miou = statistics.fmean(v["mIoU"] for v in seeds.values())
        person = statistics.fmean(v["person"] for v in seeds.values())
        closure = "—"
        if row not in ("source_only", "oracle") and walking.get("oracle"):
            common = sorted(set(seeds) & set(walking["oracle"]) & set(walking["source_only"]))
            values = [
                (seeds[s]["person"] - walking["source_only"][s]["person"])
                / (walking["oracle"][s]["person"] - walking["source_only"][s]["person"])
                for s in common
                if walking["oracle"][s]["person"] != walking["source_only"][s]["person"]
            ]
            if values:
                p = paired_interval(values)
                closure = text(p)
        lines.append(f"| {row} | {len(seeds)} | {miou:.1f} | {person:.1f} | {closure} |")
    ratios = slam_ratios(args.out)
    if args.seeds is not None:
        ratios = {
            key: {
                m: (v if m == "_ate" else {s: r for s, r in v.items() if s in args.seeds})
                for m, v in models.items()
            }
            for key, models in ratios.items()
        }
    if ratios:
        lines += [
            "",
            "H4: downstream ratio (ATE_none − ATE_model) / (ATE_none − ATE_oracle), AdaBN's "
            "masks − source-only's, paired by seed; and the protocol's ATE_model / ATE_none "
            "(lower is better; AdaBN − source-only < 0 is a gain):",
            "",
            "| system | sequence | ATE none / oracle [m] | source-only ratio (median) | "
            "AdaBN ratio (median) | AdaBN − source-only (ratio) | reading | "
            "ATE_model / ATE_none, source-only / AdaBN (medians) | "
            "AdaBN − source-only (ATE_model / ATE_none) |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for (system, sequence), models in sorted(ratios.items()):
            base, so, ab = models["_ate"], models.get("source_only", {}), models.get("adabn", {})
            seeds = sorted(set(so) & set(ab))
            ratio_diffs = [
                ab[s][0] - so[s][0] for s in seeds if ab[s][0] is not None and so[s][0] is not None
            ]
            rel_diffs = [ab[s][1] - so[s][1] for s in seeds]
            p, q = paired_interval(ratio_diffs), paired_interval(rel_diffs)

            def median(values: list) -> str:
                values = [v for v in values if v is not None]
                return f"{statistics.median(values):.3f}" if values else "—"

            oracle = "—" if base["oracle"] is None else f"{base['oracle']:.4f}"
            reading = "control" if sequence == CONTROL else one_sided(p)
            lines.append(
                f"| {system} | {sequence} | {base['none']:.4f} / {oracle} | "
                f"{median([so[s][0] for s in seeds])} | {median([ab[s][0] for s in seeds])} | "
                f"{text(p, 3)} | {reading} | {median([so[s][1] for s in seeds])} / "
                f"{median([ab[s][1] for s in seeds])} | {text(q, 3)} |"
            )
    report = "\n".join(lines)
    print(report)
    if args.markdown:
        args.markdown.write_text(report + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

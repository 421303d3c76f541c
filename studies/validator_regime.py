"""The real regime calibrates the label-free validators (``docs/results/protocol.md``, "the real
regime calibrates the label-free validators"): does a validator that a user reads on unlabelled
target frames rank the study's models as their target person IoU does, and does choosing by it
beat keeping continued source-only?

1. ``compute STUDY --out DIR --seeds 0,1,…``: ``uss-eval compare`` (as a user runs it) on the
   study's unlabelled target training sequences, every 5th frame, with the probe against 32 of
   its VOC images, once per seed over that seed's seven unsupervised models plus the two init
   rows; writes ``DIR/validators.csv`` (one row per model: row, seed, each validator).
2. ``figures --validators CSV CONFUSION.csv… [--markdown FILE]``: each validator's weighted
   Spearman correlation with the models' person IoU on the evaluation renders, and the pick per
   seed against continued source-only, paired across renders, beside "always AdaBN" and the
   labels' pick †.

    python studies/validator_regime.py compute outputs/gap/study --out outputs/gap/validators \\
        --seeds 0,1,2,3,4,5,6,7
    python studies/validator_regime.py figures --validators docs/results/gap_main/validators.csv \\
        docs/results/gap_main/confusion.csv docs/results/gap_main/confusion_s5.csv
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gap_figures  # noqa: E402  (a study script beside this one)

from uss_slam.core.verdict import weighted_spearman  # noqa: E402
from uss_slam.pipelines.experiments.tables.stats import paired_interval  # noqa: E402

UNSUPERVISED = (
    "source_only_bntrained",
    "source_only_bnreference",
    "adabn_bntrained",
    "adabn_bnreference",
    "adaptsegnet_n5_bnreference",
    "fda_bntrained",
    "fda_bntrained_adabn",
)
"""One seed's models among which a validator picks (the oracle trained on target labels)."""
INIT_ROWS = ("init", "init_adabn")
ADABN = "adabn_bntrained"
VALIDATORS = ("entropy", "im", "snd", "probe", "dynamic_share")
LOWER_IS_BETTER = {"probe"}
"""Directions fixed in the protocol before any score: higher is better but for the probe."""
FRAME_STRIDE = 5
SOURCE_FRAMES = 32


def compare_command(study: Path, models: Sequence[Path], out: Path) -> list[str]:
    """The ``uss-eval compare`` command line of one seed's group."""
    uss_eval = Path(sys.executable).parent / "uss-eval"
    command = [str(uss_eval), "compare", *map(str, models)]
    folders = sorted(p for p in (study / "data/train/target_train").iterdir() if p.is_dir())
    if not folders:
        sys.exit(f"validator_regime: error: {study}/data/train/target_train: no sequence")
    for folder in folders:
        command += ["--sequence", str(folder)]
    voc = study / "data/train/voc/VOCdevkit/VOC2012/JPEGImages"
    return command + ["--stride", str(FRAME_STRIDE), "--source", str(voc), "--source-frames",
                      str(SOURCE_FRAMES), "--out", str(out), "--quiet"]  # fmt: skip


def compute(study: Path, out: Path, seeds: Sequence[int]) -> Path:
    """Every seed's group through ``uss-eval compare``; ``out/validators.csv``."""
    rows: dict[str, dict[str, object]] = {}
    for seed in seeds:
        group_rows = [(row, "") for row in INIT_ROWS] + [(row, str(seed)) for row in UNSUPERVISED]
        names = [row + (f"_s{s}" if s else "") for row, s in group_rows]
        models = [study / "exports" / n / f"{n}.onnx" for n in names]
        missing = [str(m) for m in models if not m.is_file()]
        if missing:
            sys.exit(f"validator_regime: error: {missing[0]}: no such export (seed {seed})")
        group = out / f"compare_s{seed}"
        if not (group / "compare.json").is_file():
            subprocess.run(compare_command(study, models, group), check=True)
        scores = json.loads((group / "compare.json").read_text())["validators"]
        for name, (row, s) in zip(names, group_rows, strict=True):
            entry = {"model": name, "row": row, "seed": s}
            rows.setdefault(name, entry | {v: scores[name][v] for v in VALIDATORS})
        print(f"validators: seed {seed}: {len(names)} models", flush=True)
    path = out / "validators.csv"
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["model", "row", "seed", *VALIDATORS])
        writer.writeheader()
        writer.writerows(rows.values())
    return path


def read_validators(path: Path) -> dict[tuple[str, str], dict[str, float]]:
    """``{(row, seed): {validator: score oriented so that higher is better}}``."""
    out = {}
    with open(path, newline="") as f:
        for line, r in enumerate(csv.DictReader(f), start=2):
            try:
                values = {v: float(r[v]) for v in VALIDATORS}
            except (KeyError, ValueError) as err:
                sys.exit(f"validator_regime: error: {path}:{line}: expected a number for every "
                         f"one of {', '.join(VALIDATORS)} ({err})")  # fmt: skip
            out[(r["row"], r["seed"])] = {
                v: -x if v in LOWER_IS_BETTER else x for v, x in values.items()
            }
    return out


def truth_of(scores: dict, row: str, seed: str) -> dict[str, float]:
    """Person IoU (points) of one model per evaluation render."""
    return {render: by_seed[seed]["person"] for render, by_seed in scores[row].items()
            if seed in by_seed}  # fmt: skip


def pick_gain(scores: dict, choose: dict[str, str], seeds: Sequence[str], against: str) -> dict:
    """The chosen row of each seed minus row ``against`` of that seed, per render the mean over
    seeds, paired across renders."""
    diffs = []
    for render in sorted(scores[against]):
        per_seed = [
            scores[choose[s]][render][s]["person"] - scores[against][render][s]["person"]
            for s in seeds
        ]
        diffs.append(float(np.mean(per_seed)))
    return paired_interval(diffs)


def figures(validators: dict, scores: dict) -> list[str]:
    """The tables of the protocol's figures: per validator its weighted Spearman correlation
    and its pick per seed against continued source-only and (exploratory) always-AdaBN."""
    seeds = sorted({s for (row, s) in validators if row in UNSUPERVISED}, key=int)
    seeds = [s for s in seeds if all(s in scores[r][next(iter(scores[r]))] for r in UNSUPERVISED)]
    models = [
        (row, s) for (row, s) in validators if row in scores and (row in INIT_ROWS or s in seeds)
    ]
    mean_truth = {m: float(np.mean(list(truth_of(scores, m[0], m[1]).values()))) for m in models}
    picks: list[tuple[str, str, dict[str, str]]] = []
    for v in VALIDATORS:
        rho = weighted_spearman([validators[m][v] for m in models], [mean_truth[m] for m in models])
        choose = {s: max(UNSUPERVISED, key=lambda r, s=s: validators[(r, s)][v]) for s in seeds}
        picks.append((v, f"{rho:+.2f}", choose))
    labels = {s: max(UNSUPERVISED, key=lambda r, s=s: mean_truth[(r, s)]) for s in seeds}
    picks += [("always AdaBN", "", {s: ADABN for s in seeds}), ("labels' pick †", "", labels)]
    lines = [
        f"Models: {len(models)} (seeds {', '.join(seeds)}); truth: person IoU on "
        f"{len(scores[gap_figures.SOURCE_ONLY])} evaluation renders.",
        "",
        "| validator | weighted Spearman with person IoU | pick per seed − continued source-only, "
        "points [95%], MDE | pick − always AdaBN (exploratory) | picks (row: seeds) |",
        "|---|---|---|---|---|",
    ]
    for name, rho, choose in picks:
        gain = pick_gain(scores, choose, seeds, gap_figures.SOURCE_ONLY)
        over = pick_gain(scores, choose, seeds, ADABN)
        lines.append(
            f"| {name} | {rho} | {gap_figures.interval_text(gain)} | "
            f"{gap_figures.interval_text(over, mde=False)} | {_picks(choose)} |"
        )
    return lines


def _picks(choose: dict[str, str]) -> str:
    by_row: dict[str, list[str]] = {}
    for seed, row in choose.items():
        by_row.setdefault(row, []).append(seed)
    return "; ".join(f"{row}: {','.join(s)}" for row, s in sorted(by_row.items()))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("compute", help="uss-eval compare per seed; OUT/validators.csv")
    c.add_argument("study", type=Path)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--seeds", required=True, help="comma-separated training seeds")
    f = sub.add_parser("figures", help="the protocol's tables from the committed files")
    f.add_argument("--validators", type=Path, required=True)
    f.add_argument("confusion", type=Path, nargs="+", help="gap_study.py score's CSVs")
    f.add_argument("--markdown", type=Path, help="also write the tables to this file")
    args = parser.parse_args(argv)
    if args.command == "compute":
        try:
            seeds = [int(s) for s in args.seeds.split(",")]
        except ValueError:
            parser.error(f"--seeds: expected comma-separated integers, got {args.seeds!r}")
        print(compute(args.study, args.out, seeds))
        return
    for path in (args.validators, *args.confusion):
        if not path.is_file():
            sys.exit(f"validator_regime: error: {path}: no such file")
    text = "\n".join(figures(read_validators(args.validators),
                             gap_figures.read_scores(args.confusion, "eval"))) + "\n"  # fmt: skip
    print(text, end="")
    if args.markdown:
        args.markdown.write_text(text)


if __name__ == "__main__":
    main()

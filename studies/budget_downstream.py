"""Do the SLAM figures follow the segmentation at another training budget? The SLAM side of
``shift_probe.py`` trainings: export their last checkpoints (and the same with target BatchNorm
statistics, AdaBN), run the SLAM jobs of ``uss-experiments`` with their masks on a finished
experiment's evaluation sequences, and print the downstream ratios. Reported in
docs/results/README.md, "The board" (its 5-seed rows), from the entries of docs/results/shifts.md
("At the converged budget ...", "Five seeds at the converged budget ...").

For trainings of another budget than the experiment's (``shift_probe.py --iters N``), so that
the claim can be checked at a budget where source-only has converged without re-running the
whole grid. Each row ``R`` of ``--rows`` is ``RUNS/R_s<seed>/checkpoints/last.ckpt``; it is
exported as ``R`` and as ``R+adabn`` (statistics re-estimated on 48 evenly spaced unlabelled
target training frames of ``OUT/data/train``, as ``uss-experiments``' AdaBN exports), into
``RUNS/exports/`` (``--models`` keeps some of them). The SLAM jobs are those of
``uss-experiments`` (same overrides, 3 repeats): the harness with ``filters=[semantic]`` and
``[semantic,geometry]``, ORB-SLAM3 with the masked input (and, asked for with ``--variants
orbslam3:semantic_inpaint``, the same with ``system.blank_fill=inpaint``, its ratios taken
against the grey ground-truth-mask baseline); the unfiltered and ground-truth-mask baselines run
once per sequence. Then, per system, filter and sequence, the downstream ratio
(ATE_none − ATE_model) / (ATE_none − ATE_oracle) of every model and seed (median ATE over
repeats; on ``static_*`` sequences ATE_model / ATE_none) and each row's difference to ``--base``, paired by seed (with its mean and 95% Student-t
interval over the seeds)::

    python studies/budget_downstream.py --experiment OUT --runs RUNS --seeds 0,1 \\
        --rows source_only,adaptsegnet+adv10 [--sequences walking_xyz,walking_rpy] [--json F] \\
        [--variants harness:semantic_geometry,orbslam3:semantic] [--plot downstream.png] \\
        [--pool] [--segeval 5] [--baseline-repeats 21]

``--pool`` also pools the walking sequences given, for sequences that are renders of one preset
with other outfit draws (``uss-synth sequence --preset walking_rpy --seed S``, linked into
``OUT/data/eval/``): per system, filter and row, the median ratio over seeds × sequences, and
per seed the mean over the sequences of the row's difference to ``--base``, with its interval
over the seeds. One render decides little: which of a seed's models find the walkers depends on
the two outfits that render draws. ``--segeval N`` also scores every model on every sequence
(``uss-eval``, every N-th frame, into ``RUNS/segeval/<sequence>/<model>/``, reused when its
``eval.json`` exists): mIoU and person IoU per seed, paired the same way (pooled with
``--pool``).

``--baseline-repeats K`` runs the two baselines (unfiltered, ground-truth masks) K times
instead of 3, into ``none_rK`` / ``oracle_rK``: every row's ratio shares their ATE, so their
run-to-run spread moves all rows together (ORB-SLAM3 unfiltered on static_xyz: 3.3 / 3.7 /
4.7 mm in three repeats), and they are only two jobs per sequence. The table gives each
baseline's median with the range of its repeats.

When a system runs more than one filter (``--variants orbslam3:semantic,orbslam3:semantic_inpaint``),
each is also compared with the first, model by model: per row, the median ratio over seeds ×
walking sequences and, per seed, the mean over the sequences of filter − first filter, with its
interval over the seeds.

``--plot`` draws one panel per system, filter and sequence: each seed's ratio for every row,
joined across the rows (the pairing the differences use), the median over seeds as a bar, and
the reference lines (0 = no filter, 1 = ground-truth masks, 0.5 = the target; on ``static_*``
1 = no filter and 1.1 = the 10% a filter may cost).

Jobs whose ``metrics.json`` exists are reused (an interrupted run continues).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from uss_slam.pipelines.experiments.tables import paired_interval, paired_text

ADABN_IMAGES = 48
ADABN_BATCH_SIZE = 4
SYSTEMS = {
    "harness": {"semantic": ["filters=[semantic]"], "semantic_geometry": ["filters=[semantic,geometry]"]},
    "orbslam3": {"semantic": ["filters=[]"], "semantic_inpaint": ["filters=[]", "system.blank_fill=inpaint"]},
}  # fmt: skip
DEFAULT_VARIANTS = ("harness:semantic", "harness:semantic_geometry", "orbslam3:semantic")


def export(runs: Path, row: str, seed: int, target: list[Path]) -> dict[str, Path]:
    """``{name: onnx}`` of one training: its last checkpoint and the same with AdaBN."""
    from uss_slam.datasets.transforms import eval_transform
    from uss_slam.datasets.tum import TUMFrames
    from uss_slam.export import export_checkpoint
    from uss_slam.train.precise_bn import adabn

    ckpt = runs / f"{row}_s{seed}" / "checkpoints" / "last.ckpt"
    if not ckpt.is_file():
        raise SystemExit(f"{ckpt}: no such checkpoint (train it with shift_probe.py)")

    def prepare(net: Any) -> None:
        frames = TUMFrames(target, labels=False, transform=eval_transform())
        adabn(net, frames, images=ADABN_IMAGES, batch_size=ADABN_BATCH_SIZE)

    out = {}
    for name, options in ((row, {}), (f"{row}+adabn", {"prepare": prepare})):
        path = runs / "exports" / f"{name}_s{seed}.onnx"
        if not path.is_file():
            print(f"export {path.name}", file=sys.stderr, flush=True)
            export_checkpoint(ckpt, path, experiment=f"{name}_s{seed}", **options)
        out[name] = path
    return out


def slam(folder: Path, overrides: list[str]) -> float:
    """Median ATE RMSE over the repeats of one ``uss-slam`` job (run unless already done)."""
    return slam_repeats(folder, overrides)[0]


def slam_repeats(folder: Path, overrides: list[str]) -> tuple[float, float, float]:
    """(median, min, max) ATE RMSE over the repeats of one ``uss-slam`` job (run unless already
    done); one run: its ATE three times."""
    metrics = folder / "metrics.json"
    if not metrics.is_file():
        cmd = [sys.executable, "-m", "uss_slam.slam_eval.run", *overrides,
               f"out_dir={folder}", "progress=false"]  # fmt: skip
        print(" ".join(cmd[3:]), file=sys.stderr, flush=True)
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f"{folder}: uss-slam failed: {done.stderr.strip()[-600:]}")
    data = json.loads(metrics.read_text())
    repeats = data.get("ate_rmse_repeats")
    if not repeats:
        return (float(data["ate"]["rmse"]),) * 3
    median = float(repeats["median"])
    return median, float(repeats.get("min", median)), float(repeats.get("max", median))


def baseline_folder(name: str, repeats: int) -> str:
    """``none`` / ``oracle`` with the 3 repeats of every job; ``none_r21`` ... otherwise."""
    return name if repeats == 3 else f"{name}_r{repeats}"


def segeval(folder: Path, onnx: Path, sequence: Path, stride: int) -> dict[str, float]:
    """mIoU and person IoU of one model on one labelled sequence (``uss-eval``, every
    ``stride``-th frame; run unless ``folder/eval.json`` exists)."""
    result = folder / "eval.json"
    if not result.is_file():
        cmd = [str(Path(sys.executable).parent / "uss-eval"), str(onnx), "--sequence",
               str(sequence), "--stride", str(stride), "--threads", "1", "--out", str(folder)]  # fmt: skip
        print(" ".join(cmd[1:]), file=sys.stderr, flush=True)
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f"{folder}: uss-eval failed: {done.stderr.strip()[-600:]}")
    data = json.loads(result.read_text())
    return {"mIoU": float(data["mIoU"]), "person": float(data["IoU"]["person"])}


def pooled(
    per_sequence: dict[str, dict[str, dict[int, float]]], rows: list[str], base: str,
    seeds: list[int],
) -> dict[str, Any]:  # fmt: skip
    """``{sequence: {row: {seed: value}}}`` pooled over the sequences: per row the median over
    seeds × sequences and, for every row but ``base``, the per-seed mean over the sequences of
    row − base, with its mean and 95% interval over the seeds (:func:`paired_interval`)."""
    out: dict[str, Any] = {}
    sequences = list(per_sequence)
    for row in rows:
        values = [per_sequence[q][row][s] for q in sequences for s in seeds]
        entry: dict[str, Any] = {"median": statistics.median(values), "n": len(values)}
        if row != base:
            entry["paired"] = paired_interval([
                statistics.fmean(per_sequence[q][row][s] - per_sequence[q][base][s]
                                 for q in sequences)
                for s in seeds
            ])  # fmt: skip
        out[row] = entry
    return out


def pooled_lines(title: str, pool: dict[str, Any], base: str) -> list[str]:
    lines = [f"| {title} | median over seeds × sequences | − {base}, per seed the mean over the "
             "sequences |", "|---|---|---|"]  # fmt: skip
    for row, entry in pool.items():
        paired = paired_text(entry["paired"]) if "paired" in entry else "—"
        lines.append(f"| {row} | {entry['median']:.3f} (n = {entry['n']}) | {paired} |")
    return lines


def filter_comparisons(
    ate: dict[str, Any], walking: list[str], rows: list[str], seeds: list[int]
) -> dict[str, tuple[list[str], dict[str, Any]]]:
    """Per system that ran more than one filter on every walking sequence: (its filters, per
    row :func:`pooled` over the sequences with the filters as its rows, against the first)."""
    out = {}
    for system in SYSTEMS:
        ran = [v for v in SYSTEMS[system]
               if walking and all(v in ate.get(f"{system}/{q}", {}) for q in walking)]  # fmt: skip
        if len(ran) < 2:
            continue
        out[system] = (ran, {
            row: pooled({q: {v: {s: ate[f"{system}/{q}"][v][row][s]["ratio"] for s in seeds}
                             for v in ran} for q in walking}, ran, ran[0], seeds)
            for row in rows
        })  # fmt: skip
    return out


def downstream_ratio(sequence: str, base: dict[str, float], ate: float) -> float:
    """(ATE_none − ATE) / (ATE_none − ATE_GT masks); on a sequence without walkers
    (``static_*``, where the masks have nothing to remove) ATE / ATE_none instead: a filter
    should cost nothing there (target: within 10%)."""
    if sequence.startswith("static"):
        return ate / base["none"]
    return (base["none"] - ate) / (base["none"] - base["oracle"])


def baseline_text(base: dict[str, Any]) -> str:
    """``3.7 (3.3–4.7) / 3.6 (3.2–3.7)``: the baselines' median ATE in mm with their repeats'
    range (a baseline of one run, or read from an older output: just the median)."""
    parts = []
    for name in ("none", "oracle"):
        text = f"{1000 * base[name]:.1f}"
        low, high = base.get(f"{name}_range", (base[name], base[name]))
        if low != high:
            text += f" ({1000 * low:.1f}–{1000 * high:.1f})"
        parts.append(text)
    return " / ".join(parts)


def paired_difference(
    per: dict[str, dict[int, dict[str, float]]],
    name: str,
    base: str,
    seeds: list[int],
    key: str = "ratio",
) -> dict[str, Any]:
    """Row ``name``'s ``key`` (the downstream ratio, or a segmentation metric) minus ``base``'s,
    paired by seed: the values, how many are positive, their mean and its 95% Student-t
    interval (None below two seeds)."""
    return paired_interval([per[name][s][key] - per[base][s][key] for s in seeds])


def plot_ratios(ate: dict[str, Any], rows: list[str], seeds: list[int], path: Path) -> Path:
    """The downstream ratios of ``ate`` (``{"system/sequence": {"baselines": ..., variant:
    {row: {seed: {"ratio": r}}}}}``) as a PNG at ``path``; see the module docstring."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(key, v) for key, cell in ate.items() for v in cell if v != "baselines"]
    if not panels:
        raise ValueError("no downstream ratios to plot")
    cols = min(len(panels), 4)
    n_rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(n_rows, cols, figsize=(3.2 * cols, 3.2 * n_rows), squeeze=False)
    x = list(range(len(rows)))
    colours = plt.get_cmap("tab10")
    for ax, (key, variant) in zip(axes.flat, panels, strict=False):
        system, sequence = key.split("/")
        per = ate[key][variant]
        for k, seed in enumerate(seeds):
            ys = [per[r][seed]["ratio"] if seed in per.get(r, {}) else float("nan") for r in rows]
            ax.plot(x, ys, "o-", color=colours(k % 10), alpha=0.7, lw=1, ms=4, label=f"seed {seed}")
        for i, r in enumerate(rows):
            values = [per[r][s]["ratio"] for s in seeds if s in per.get(r, {})]
            if values:
                m = statistics.median(values)
                ax.plot([i - 0.25, i + 0.25], [m, m], color="black", lw=2.5)
        static = sequence.startswith("static")
        for y, style in (
            ((1.0, "-"), (1.1, ":")) if static else ((0.0, "-"), (1.0, "-"), (0.5, ":"))
        ):
            ax.axhline(y, color="grey", lw=0.8, ls=style)
        ax.set_xticks(x, rows, rotation=30, ha="right", fontsize=7)
        ax.set_title(f"{system}, {variant}\n{sequence}", fontsize=9)
        ax.set_ylabel("ATE / ATE no filter" if static else "downstream ratio", fontsize=8)
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=6, loc="lower right")
    fig.suptitle(
        "Downstream ratio per seed (lines: same seed; bars: median over seeds)", fontsize=10
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--experiment", type=Path, required=True, help="uss-experiments output")
    parser.add_argument("--runs", type=Path, required=True, help="shift_probe.py --runs folder")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--rows", default="source_only,adaptsegnet+adv10")
    parser.add_argument("--base", default="source_only", help="the row differences are taken to")
    parser.add_argument("--sequences", default="walking_xyz,walking_rpy")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--plot", type=Path, help="also draw the ratios per seed into this PNG")
    every = [f"{system}:{v}" for system, variants in SYSTEMS.items() for v in variants]
    parser.add_argument("--variants", default=",".join(DEFAULT_VARIANTS),
                        help=f"system:filter cells to run (default: {','.join(DEFAULT_VARIANTS)}; "
                             f"all: {','.join(every)})")  # fmt: skip
    parser.add_argument("--models",
                        help="only these of the exported models (default: every row R of --rows "
                             "and R+adabn), e.g. source_only,source_only+adabn")  # fmt: skip
    parser.add_argument("--pool", action="store_true",
                        help="also pool the walking sequences (renders of one preset): medians "
                             "over seeds x sequences, per-seed differences averaged over them")  # fmt: skip
    parser.add_argument("--segeval", type=int, metavar="N",
                        help="also score every model on every sequence (uss-eval, every N-th "
                             "frame): mIoU and person IoU, paired by seed")  # fmt: skip
    parser.add_argument("--baseline-repeats", type=int, default=3, metavar="K",
                        help="repeats of the unfiltered and ground-truth-mask baselines "
                             "(default 3, as every model's job)")  # fmt: skip
    args = parser.parse_args(argv)
    if args.baseline_repeats < 1:
        parser.error(f"--baseline-repeats: a count >= 1, got {args.baseline_repeats}")
    if args.segeval is not None and args.segeval < 1:
        parser.error(f"--segeval: a frame stride >= 1, got {args.segeval}")
    chosen = args.variants.split(",")
    unknown = [v for v in chosen if v not in every]
    if unknown:
        parser.error(f"--variants: unknown {','.join(unknown)}; choose from {','.join(every)}")
    out = args.experiment
    vocabulary = out / "data" / "orbslam3_vocabulary" / "vocabulary.txt"
    sequences = args.sequences.split(",")
    for p in [vocabulary, *(out / "data" / "eval" / s for s in sequences)]:
        if not p.exists():
            parser.error(f"--experiment: {p} is missing (a finished uss-experiments output?)")
    target = sorted(p for p in (out / "data" / "train" / "target_train").iterdir() if p.is_dir())
    seeds = [int(s) for s in args.seeds.split(",")]
    models = {seed: {} for seed in seeds}
    names = [n for row in args.rows.split(",") for n in (row, f"{row}+adabn")]
    kept = args.models.split(",") if args.models else names
    unknown = [m for m in kept if m not in names]
    if unknown:
        parser.error(f"--models: unknown {','.join(unknown)}; the rows give {','.join(names)}")
    if args.base not in kept:
        parser.error(f"--models: must include --base {args.base}")
    for seed in seeds:
        for row in args.rows.split(","):
            named = export(args.runs, row, seed, target)
            models[seed].update({n: named[n] for n in named if n in kept})
    system_args = {
        "harness": [],
        "orbslam3": ["system=orbslam3", f"system.vocabulary={vocabulary}"],
    }
    repeats_key = {"harness": "slam.repeats", "orbslam3": "system.repeats"}
    ate: dict[str, Any] = {}
    root = args.runs / "slam"
    for sequence in sequences:
        path = f"sequence.path={out / 'data' / 'eval' / sequence}"
        for system, variants in SYSTEMS.items():
            variants = {v: o for v, o in variants.items() if f"{system}:{v}" in chosen}
            if not variants:
                continue
            common = [path, *system_args[system], f"{repeats_key[system]}=3"]
            k = args.baseline_repeats
            baseline = [path, *system_args[system], f"{repeats_key[system]}={k}"]
            filters_off = "filters=[]"
            folder = root / system / sequence
            none = slam_repeats(folder / baseline_folder("none", k),
                                [*baseline, "segmenter=none", filters_off])  # fmt: skip
            oracle_filter = "filters=[semantic]" if system == "harness" else filters_off
            oracle = slam_repeats(folder / baseline_folder("oracle", k),
                                  [*baseline, "segmenter=labels", oracle_filter])  # fmt: skip
            base = {"none": none[0], "oracle": oracle[0], "repeats": k,
                    "none_range": none[1:], "oracle_range": oracle[1:]}  # fmt: skip
            ate[f"{system}/{sequence}"] = {"baselines": base}
            for variant, extra in variants.items():
                for seed, named in models.items():
                    for name, onnx in named.items():
                        job = root / system / sequence / variant / f"{name}_s{seed}"
                        a = slam(job, [*common, "segmenter=onnx", f"segmenter.path={onnx}", *extra])
                        ratio = downstream_ratio(sequence, base, a)
                        ate[f"{system}/{sequence}"].setdefault(variant, {}).setdefault(name, {})[seed] = {
                            "ate": a, "ratio": ratio}  # fmt: skip
    lines = [
        "| system, filter, sequence | baselines none / GT masks [mm] | "
        + " | ".join(models[seeds[0]]) + f" | each row − {args.base}, paired by seed |",
        "|---" * (len(models[seeds[0]]) + 3) + "|",
    ]  # fmt: skip
    paired_all: dict[str, Any] = {}
    for key, cell in ate.items():
        base = cell["baselines"]
        for variant in (v for v in cell if v != "baselines"):
            per = cell[variant]
            cols = []
            for name in models[seeds[0]]:
                rs = [per[name][s]["ratio"] for s in seeds]
                cols.append(" / ".join(f"{r:.2f}" for r in rs))
            diffs = []
            for name in models[seeds[0]]:
                if name == args.base:
                    continue
                paired = paired_difference(per, name, args.base, seeds)
                paired_all.setdefault(key, {}).setdefault(variant, {})[name] = paired
                diffs.append(f"{name} {paired_text(paired)}")
            system, sequence = key.split("/")
            lines.append(
                f"| {system}, {variant}, {sequence} | {baseline_text(base)} | "
                + " | ".join(cols)
                + " | "
                + "; ".join(diffs)
                + " |"
            )
    print(
        f"Downstream ratio per seed ({', '.join(map(str, seeds))}); median ATE of 3 repeats each"
        f" (the baselines: of {args.baseline_repeats}, with their range)."
    )
    print("\n".join(lines))
    medians = {
        key: {
            v: {n: statistics.median(x["ratio"] for x in s.values()) for n, s in per.items()}
            for v, per in cell.items()
            if v != "baselines"
        }
        for key, cell in ate.items()
    }
    rows = list(models[seeds[0]])
    walking = [q for q in sequences if not q.startswith("static")]
    pools: dict[str, Any] = {}
    if args.pool and len(walking) > 1:
        for key_variant in sorted({(k.split("/")[0], v) for k, c in ate.items() for v in c
                                   if v != "baselines"}):  # fmt: skip
            system, variant = key_variant
            per_sequence = {
                q: {r: {s: x["ratio"] for s, x in ate[f"{system}/{q}"][variant][r].items()}
                    for r in rows}
                for q in walking
                if variant in ate.get(f"{system}/{q}", {})
            }  # fmt: skip
            pool = pooled(per_sequence, rows, args.base, seeds)
            pools[f"{system}/{variant}"] = pool
            print()
            print(f"Pooled over {', '.join(per_sequence)}: downstream ratio")
            print("\n".join(pooled_lines(f"{system}, {variant}", pool, args.base)))
    for system, (ran, by_row) in filter_comparisons(ate, walking, rows, seeds).items():
        print()
        print(f"{system}: each filter against {ran[0]}, same model, seed and sequence; pooled "
              f"over {', '.join(walking)}: downstream ratio")  # fmt: skip
        for row, pool in by_row.items():
            pools[f"{system}/filters/{row}"] = pool
            print("\n".join(pooled_lines(row, pool, ran[0])))
    seg: dict[str, Any] = {}
    if args.segeval is not None:
        for q in sequences:
            for seed, named in models.items():
                for name, onnx in named.items():
                    folder = args.runs / "segeval" / q / f"{name}_s{seed}"
                    seg.setdefault(q, {}).setdefault(name, {})[seed] = segeval(
                        folder, onnx, out / "data" / "eval" / q, args.segeval
                    )
        for metric in ("person", "mIoU"):
            print()
            label = "person IoU" if metric == "person" else "mIoU"
            print(f"{label} per seed ({', '.join(map(str, seeds))}), every {args.segeval}th frame, "
                  f"each row − {args.base} paired by seed")  # fmt: skip
            for q in sequences:
                cols = []
                for name in rows:
                    vs = [seg[q][name][s][metric] for s in seeds]
                    paired = "" if name == args.base else " " + paired_text(
                        paired_difference(seg[q], name, args.base, seeds, metric))  # fmt: skip
                    cols.append(f"{name} " + " / ".join(f"{v:.3f}" for v in vs) + paired)
                print(f"- {q}: " + "; ".join(cols))
            if args.pool and len(walking) > 1:
                per_sequence = {q: {r: {s: seg[q][r][s][metric] for s in seeds} for r in rows}
                                for q in walking}  # fmt: skip
                pool = pooled(per_sequence, rows, args.base, seeds)
                pools[f"segeval/{metric}"] = pool
                print("\n".join(pooled_lines(f"{metric}, pooled over {', '.join(walking)}",
                                              pool, args.base)))  # fmt: skip
    if args.json:
        data = {"ate": ate, "paired": paired_all, "medians": medians, "pooled": pools,
                "segeval": seg}  # fmt: skip
        args.json.write_text(json.dumps(data, default=str))
    if args.plot:
        print(f"plot: {plot_ratios(ate, rows, seeds, args.plot)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

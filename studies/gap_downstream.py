"""The real-regime study's downstream test (``docs/results/protocol.md``, "the real regime
downstream"): do the masks of the method that gained make SLAM more accurate than continued
source-only's, on the study's evaluation renders? Written as small committed files that every
figure is recomputed from.

Sub-commands (``STUDY`` is the study's ``uss-experiments`` folder, ``RENDERS`` the folder of its
renders ``<preset>_<seed>``; ``--blocks`` as ``gap_study.py``):

- ``mediator STUDY --renders RENDERS --blocks B,... --models M,... --out FILE.csv``: per (model,
  render), on every ``--stride``-th of the first ``--first`` frames, the harness's ORB keypoints
  split into *walker* keypoints (inside the true person mask dilated ``--dilation`` px) and
  *static* ones, and how many of each the model's argmax person mask (dilated the same way, as
  the semantic filter does) removes. Columns ``walker_kp, walker_removed, static_kp,
  static_removed`` (counts pooled over the frames).
- ``run STUDY --renders RENDERS --blocks B,... --models M,... --runs RUNS --system harness|orbslam3
  [--vocabulary V]``: the SLAM runs, each one ``uss-slam`` into ``RUNS/<system>/<render>/<run>``
  (``none``: no filter; ``oracle``: ground-truth masks; a model: ``segmenter=onnx`` with its
  export), ``filters=[semantic]``, ``slam.repeats=3``; a run whose ``metrics.json`` exists is kept
  (so a stopped job resumes). Blocks run in the order given.
- ``collect RUNS --out FILE.csv``: one row per run: median ATE RMSE of the repeats, their range,
  the tracked fraction.
- ``figures --mediator FILE.csv --slam FILE.csv --method ROW --base ROW``: the protocol's
  figures (paired differences over renders of the per-render seed means: mean, 95% interval,
  MDE, the reading rule's word), as Markdown on stdout.

Seeds of the models are the ``_s<seed>`` suffix of their names (``adabn_bntrained_s0``).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gap_study import (  # noqa: E402
    MODEL,
    StudyError,
    exports,
    parse_blocks,
    render_folders,
    write_csv,
)

PERSON = 1
"""The person class id (``core.classes.CLASS_NAMES``)."""
SMALLEST_EFFECT = 0.05
"""The reading rule's smallest effect of interest (shares and ratios alike, protocol.md)."""
BASELINES = ("none", "oracle")


def _kernel(dilation: int) -> np.ndarray:
    import cv2

    size = 2 * dilation + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def keypoint_counts(truth: np.ndarray, pred_person: np.ndarray, xy: np.ndarray,
                    kernel: np.ndarray) -> dict[str, int]:  # fmt: skip
    """Walker / static keypoints of one frame and how many of each the predicted mask removes.

    ``truth``: (H, W) class ids; ``pred_person``: (H, W) bool; ``xy``: (K, 2) pixel coordinates
    (x, y); ``kernel``: the dilation's structuring element (applied to both masks)."""
    import cv2

    on_walker = cv2.dilate((truth == PERSON).astype(np.uint8), kernel) > 0
    removes = cv2.dilate(pred_person.astype(np.uint8), kernel) > 0
    xi = np.clip(np.round(xy[:, 0]).astype(int), 0, truth.shape[1] - 1)
    yi = np.clip(np.round(xy[:, 1]).astype(int), 0, truth.shape[0] - 1)
    walker, removed = on_walker[yi, xi], removes[yi, xi]
    return {
        "walker_kp": int(walker.sum()),
        "walker_removed": int((walker & removed).sum()),
        "static_kp": int((~walker).sum()),
        "static_removed": int((~walker & removed).sum()),
    }


def mediator(study: Path, renders: list, models: list[str], stride: int, first: int,
             dilation: int) -> list[dict]:  # fmt: skip
    """One row per (model, render): the keypoint counts pooled over the scored frames."""
    from uss_slam.slam_eval.frontend.orb import OrbConfig, OrbExtractor
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter
    from uss_slam.slam_eval.sequence import TumSequence

    found = exports(study, models)
    nets = {m: OnnxSegmenter(path, threads=1) for m, _, _, path in found}
    kernel = _kernel(dilation)
    rows = []
    for preset, block, seed, folder in renders:
        seq = TumSequence(folder, load_labels=True, stride=stride, max_frames=-(-first // stride))
        extractor = OrbExtractor(OrbConfig(), seq.camera)
        totals: dict[str, dict[str, int]] = {m: defaultdict(int) for m in nets}
        for k in range(len(seq)):
            frame = seq.load(k)
            xy = extractor(frame.gray, frame.depth).xy
            for m, net in nets.items():
                pred = net.infer(frame.rgb) == PERSON
                for key, v in keypoint_counts(frame.labels, pred, xy, kernel).items():
                    totals[m][key] += v
        for model, row, mseed, _ in found:
            rows.append({"model": model, "row": row, "seed": mseed, "preset": preset,
                         "block": block, "render_seed": seed, **totals[model]})  # fmt: skip
        print(f"mediator {folder.name}: {len(nets)} models", flush=True)
    return rows


def slam_command(system: str, render: Path, run: str, onnx: Path | None, out: Path,
                 vocabulary: Path | None) -> list[str]:  # fmt: skip
    """The ``uss-slam`` command line of one run (``none``, ``oracle`` or a model's export)."""
    exe = Path(sys.executable).with_name("uss-slam")
    cmd = [str(exe), f"sequence.path={render}", "slam.repeats=3", f"out_dir={out}",
           "progress=false"]  # fmt: skip
    if system == "orbslam3":
        if vocabulary is None:
            raise StudyError("--vocabulary: required with --system orbslam3")
        cmd += ["system=orbslam3", f"system.vocabulary={vocabulary}"]
    if run == "oracle":
        cmd += ["segmenter=labels", "filters=[semantic]"]
    elif run != "none":
        cmd += ["segmenter=onnx", f"segmenter.path={onnx}", "filters=[semantic]"]
    return cmd


def run_slam(study: Path, renders: list, models: list[str], runs: Path, system: str,
             vocabulary: Path | None) -> None:  # fmt: skip
    found = {m: path for m, _, _, path in exports(study, models)}
    for _preset, _block, _seed, folder in renders:
        for run in (*BASELINES, *found):
            out = runs / system / folder.name / run
            if (out / "metrics.json").is_file():
                continue
            cmd = slam_command(system, folder, run, found.get(run), out, vocabulary)
            done = subprocess.run(cmd, capture_output=True, text=True)
            if done.returncode != 0:
                tail = (done.stderr or done.stdout).strip().splitlines()[-1:]
                raise StudyError(f"{out}: uss-slam failed ({' '.join(tail)})")
            print(f"{system} {folder.name} {run}", flush=True)


def collect(runs: Path) -> list[dict]:
    """One row per finished run under ``RUNS/<system>/<render>/<run>/metrics.json``."""
    rows = []
    for path in sorted(runs.glob("*/*/*/metrics.json")):
        run, render, system = path.parent.name, path.parent.parent.name, path.parents[2].name
        metrics = json.loads(path.read_text())
        reps = metrics.get("ate_rmse_repeats") or {}
        ate = reps.get("median", (metrics.get("ate") or {}).get("rmse"))
        match = MODEL.match(run)
        assert match is not None
        preset, _, seed = render.rpartition("_")
        rows.append({"system": system, "render": render, "preset": preset,
                     "render_seed": int(seed), "run": run, "row": match["row"],
                     "seed": match["seed"] or "", "ate_median": ate,
                     "ate_min": reps.get("min", ate), "ate_max": reps.get("max", ate),
                     "tracked_fraction": metrics.get("tracked_fraction")})  # fmt: skip
    if not rows:
        raise StudyError(f"{runs}: no finished run (*/*/*/metrics.json)")
    return rows


def read_csv(path: Path) -> list[dict]:
    if not path.is_file():
        raise StudyError(f"{path}: no such file")
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def paired(diffs: list[float]) -> dict[str, float]:
    """Mean, 95% two-sided Student-t interval, MDE at 80% power (the experiment tables'
    :func:`paired_interval`) and the one-sided p (> 0) of paired differences (one per render)."""
    from scipy import stats

    from uss_slam.pipelines.experiments.tables.stats import paired_interval

    p = paired_interval(diffs)
    if p["interval"] is None:
        raise StudyError(f"fewer than two paired renders ({len(diffs)}): no interval")
    n, mean = p["n"], p["mean"]
    s = float(np.std(diffs, ddof=1))
    p_one = float(stats.t.sf(mean / (s / math.sqrt(n)), n - 1)) if s > 0 else math.nan
    return {"n": n, "mean": mean, "lo": p["interval"][0], "hi": p["interval"][1],
            "mde": p["mde"], "p_one_sided": p_one, "above_0": p["positive"]}  # fmt: skip


def reading(stat: dict[str, float]) -> str:
    """The protocol's reading rule: shown / refuted / not shown."""
    if stat["lo"] > 0 or stat["hi"] < 0:
        return "shown" if stat["lo"] > 0 else "shown (negative)"
    if stat["hi"] < SMALLEST_EFFECT:
        return f"refuted (no effect >= {SMALLEST_EFFECT:g})"
    return "not shown"


def per_render(values: dict[tuple[str, str], list[float]], method: str,
               base: str) -> list[float]:  # fmt: skip
    """Per render: mean over seeds of ``method`` − mean over seeds of ``base``."""
    return list(render_diffs(values, method, base).values())


def render_diffs(values: dict[tuple[str, str], list[float]], method: str,
                 base: str) -> dict[str, float]:  # fmt: skip
    """``{render: mean over seeds of method − mean over seeds of base}``, renders in order."""
    out = {}
    for r in sorted({r for (r, row) in values if row in (method, base)}):
        a, b = values.get((r, method)), values.get((r, base))
        if a and b:
            out[r] = float(np.mean(a) - np.mean(b))
    return out


def link(walker: dict[str, float], ratio: dict[str, float]) -> str | None:
    """Exploratory: Spearman correlation across renders of the walker-share difference with
    the downstream-ratio difference (renders in both)."""
    from scipy import stats

    common = sorted(set(walker) & set(ratio))
    if len(common) < 4 or any(len({d[r] for r in common}) == 1 for d in (walker, ratio)):
        return None  # too few renders, or a constant difference: no rank correlation
    rho, p = stats.spearmanr([walker[r] for r in common], [ratio[r] for r in common])
    return f"Spearman {rho:+.2f} (p {p:.2g}, {len(common)} renders)"


def mediator_values(rows: list[dict]) -> dict[str, dict[tuple[str, str], list[float]]]:
    out: dict[str, dict] = {
        "walker_removed": defaultdict(list),
        "static_removed": defaultdict(list),
    }
    for r in rows:
        render = f"{r['preset']}_{r['render_seed']}"
        for share, total in (("walker_removed", "walker_kp"), ("static_removed", "static_kp")):
            if int(r[total]) > 0:
                out[share][(render, r["row"])].append(int(r[share]) / int(r[total]))
    return out


def slam_ratios(rows: list[dict], system: str) -> dict[tuple[str, str], list[float]]:
    """``(render, row) -> [ratio per seed]``: (ATE_none − ATE_model) / (ATE_none − ATE_oracle)."""
    by_render: dict[str, dict[str, float]] = defaultdict(dict)
    for r in rows:
        if r["system"] == system and r["ate_median"] not in ("", "None"):
            by_render[r["render"]][r["run"]] = float(r["ate_median"])
    out: dict[tuple[str, str], list[float]] = defaultdict(list)
    for render, runs in by_render.items():
        if not all(b in runs for b in BASELINES) or runs["none"] == runs["oracle"]:
            continue
        gap = runs["none"] - runs["oracle"]
        for run, ate in runs.items():
            if run in BASELINES:
                continue
            match = MODEL.match(run)
            assert match is not None
            out[(render, match["row"])].append((runs["none"] - ate) / gap)
    return out


def _line(label: str, stat: dict[str, float], digits: int = 3) -> str:
    f = f"{{:+.{digits}f}}"
    return (f"| {label} | {f.format(stat['mean'])} [{f.format(stat['lo'])}, "
            f"{f.format(stat['hi'])}] | {stat['mde']:.{digits}f} | {stat['above_0']}/{stat['n']} "
            f"| {stat['p_one_sided']:.3g} | {reading(stat)} |")  # fmt: skip


def figures(mediator_rows: list[dict], slam_rows: list[dict], method: str, base: str) -> str:
    head = ("| figure (method − base, per render, mean of seeds) | mean [95% CI] | MDE | "
            "renders > 0 | p (one-sided, > 0) | reading |\n|---|---|---|---|---|---|")  # fmt: skip
    lines = [f"{method} − {base}; reading rule: shown / refuted below +{SMALLEST_EFFECT:g} / "
             "not shown.", "", head]  # fmt: skip
    for share, values in mediator_values(mediator_rows).items():
        lines.append(_line(f"mediator: {share}", paired(per_render(values, method, base))))
    medians = []
    walker = render_diffs(mediator_values(mediator_rows)["walker_removed"], method, base)
    for system in sorted({r["system"] for r in slam_rows}):
        ratios = slam_ratios(slam_rows, system)
        diffs = per_render(ratios, method, base)
        corr = link(walker, render_diffs(ratios, method, base))
        if corr:
            medians.append(f"- {system}: walker-share difference against ratio difference "
                           f"across renders (exploratory): {corr}")  # fmt: skip
        if len(diffs) > 1:
            lines.append(_line(f"{system}: downstream ratio", paired(diffs)))
        for row in (method, base):
            vals = [v for (_, r), vs in ratios.items() if r == row for v in vs]
            if vals:
                medians.append(f"- {system}, {row}: median ratio {np.median(vals):+.3f} over "
                               f"{len(vals)} (render, seed) runs")  # fmt: skip
    return "\n".join([*lines, "", *medians, *static_lines(slam_rows, (method, base))])


def static_lines(rows: list[dict], names: tuple[str, ...]) -> list[str]:
    """On renders with nothing moving (``static_*``): each row's ATE_model / ATE_none per seed
    (the control: a mask that removes static keypoints costs accuracy there)."""
    out = []
    for system in sorted({r["system"] for r in rows}):
        mine = [r for r in rows if r["system"] == system and r["preset"].startswith("static")]
        for render in sorted({r["render"] for r in mine}):
            here = {r["run"]: r for r in mine if r["render"] == render}
            if "none" not in here or here["none"]["ate_median"] in ("", "None"):
                continue
            ref = float(here["none"]["ate_median"])
            for row in names:
                ratios = [float(r["ate_median"]) / ref for r in here.values()
                          if r["row"] == row and r["ate_median"] not in ("", "None")]  # fmt: skip
                if ratios:
                    seeds = ", ".join(f"x{v:.2f}" for v in ratios)
                    out.append(f"- {system}, {render} (nothing moves; no filter {ref:.4f} m), "
                               f"{row}: ATE / no filter {seeds} (per seed)")  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    sub = p.add_subparsers(dest="cmd", required=True)
    for name in ("mediator", "run"):
        s = sub.add_parser(name)
        s.add_argument("study", type=Path)
        s.add_argument("--renders", type=Path, required=True)
        s.add_argument("--blocks", type=parse_blocks, required=True)
        s.add_argument("--models", required=True, help="comma-separated export names")
    sub.choices["mediator"].add_argument("--out", type=Path, required=True)
    sub.choices["mediator"].add_argument("--stride", type=int, default=5)
    sub.choices["mediator"].add_argument("--first", type=int, default=100)
    sub.choices["mediator"].add_argument("--dilation", type=int, default=5)
    sub.choices["run"].add_argument("--runs", type=Path, required=True)
    sub.choices["run"].add_argument("--system", choices=("harness", "orbslam3"), required=True)
    sub.choices["run"].add_argument("--vocabulary", type=Path)
    s = sub.add_parser("collect")
    s.add_argument("runs", type=Path)
    s.add_argument("--out", type=Path, required=True)
    s = sub.add_parser("figures")
    s.add_argument("--mediator", type=Path, required=True)
    s.add_argument("--slam", type=Path, required=True)
    s.add_argument("--method", default="adabn_bntrained")
    s.add_argument("--base", default="source_only_bntrained")
    a = p.parse_args(argv)
    if a.cmd in ("mediator", "run"):
        renders = render_folders(a.renders, a.blocks)
        models = [m for m in a.models.split(",") if m]
    if a.cmd == "mediator":
        write_csv(mediator(a.study, renders, models, a.stride, a.first, a.dilation), a.out)
    elif a.cmd == "run":
        run_slam(a.study, renders, models, a.runs, a.system, a.vocabulary)
    elif a.cmd == "collect":
        write_csv(collect(a.runs), a.out)
    else:
        print(figures(read_csv(a.mediator), read_csv(a.slam), a.method, a.base))


if __name__ == "__main__":
    main()

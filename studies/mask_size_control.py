"""Do the adapted segmenter's masks help SLAM only because they are larger? A control: the same SLAM
jobs with the baseline model's person masks grown to the adapted model's size, without any
adaptation. Reported in docs/results/README.md, "2026-12-04 — source-only with a lower person
threshold (a control)".

For each seed of a ``uss-experiments`` output folder, the person probability threshold of the
``--base`` model (default ``source_only``; ``uss-slam segmenter.threshold``) is chosen so that
its mean predicted person share on the *unlabelled* target training frames (every 4th frame of
``OUT/data/train/target_train/*``) equals that of the ``--like`` model (default
``adaptsegnet_n5``, argmax) on the same frames: no labels and no evaluation frame are used to
choose it. Then every SLAM job of the grid that ran the base model with the semantic filters
(``OUT/jobs/slam.json``) runs again with that threshold, into ``OUT/mask_size/``, and the table
puts the base model at argmax, the base model grown and the like model side by side, as
downstream ratios (ATE / unfiltered ATE on ``static_xyz``) with the paired differences::

    python studies/mask_size_control.py --experiment OUT [--base source_only]
        [--like adaptsegnet_n5] [--seeds 0,1,2] [--sequences walking_xyz,walking_rpy,static_xyz]
        [--systems harness,orbslam3] [--json out.json]

A finished job (``metrics.json`` beside a ``control.json`` naming its threshold) is reused.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter
from uss_slam.testing.downstream import slam_ratios

PERSON = CLASS_NAMES.index("person")
VARIANTS = {"harness": ("semantic", "semantic_geometry"), "orbslam3": ("semantic",)}
"""The SLAM jobs of a model that the control repeats, per system."""


def target_frames(out: Path, every: int = 4) -> list[np.ndarray]:
    """Every ``every``-th RGB frame of the unlabelled target training sequences (RGB uint8)."""
    root = out / "data" / "train" / "target_train"
    paths = [p for d in sorted(root.glob("*")) for p in sorted((d / "rgb").glob("*.png"))[::every]]
    if not paths:
        raise SystemExit(f"{root}: no target training frames (expected <sequence>/rgb/*.png)")
    frames = []
    for p in paths:
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            raise SystemExit(f"{p}: cannot read the image")
        frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    return frames


def person_share(model: Path, frames: Sequence[np.ndarray], threshold: float | None) -> float:
    """Mean share of pixels ``model`` labels person (``threshold``: uss-slam's)."""
    seg = OnnxSegmenter(model, threshold=threshold, threads=1)
    return float(np.mean([(seg.infer(f) == PERSON).mean() for f in frames]))


def match_threshold(share: Callable[[float], float], wanted: float, lo: float = 0.02,
                    hi: float = 0.98, steps: int = 10) -> float:  # fmt: skip
    """The threshold at which ``share`` (decreasing in the threshold) is closest to ``wanted``,
    by bisection over ``[lo, hi]``, to two decimals."""
    if share(lo) <= wanted:
        return lo
    if share(hi) >= wanted:
        return hi
    for _ in range(steps):
        mid = (lo + hi) / 2
        if share(mid) > wanted:
            lo = mid
        else:
            hi = mid
    return round((lo + hi) / 2, 2)


def base_jobs(out: Path, model: str, sequences: Sequence[str], systems: Sequence[str]
              ) -> dict[str, list[str]]:  # fmt: skip
    """The grid's SLAM jobs of ``model`` with a semantic filter: id -> uss-slam overrides."""
    plan = out / "jobs" / "slam.json"
    try:
        cells = json.loads(plan.read_text())["cells"]
    except (OSError, ValueError, KeyError) as error:
        raise SystemExit(f"{plan}: cannot read the grid's SLAM jobs ({error})") from None
    jobs = {}
    for system in systems:
        for seq in sequences:
            for variant in VARIANTS[system]:
                job = f"slam/{system}/{seq}/{variant}/{model}"
                if job in cells:
                    ov = cells[job]["key"]["overrides"]
                    jobs[job] = [o.replace("$OUT", str(out)) for o in ov]
    if not jobs:
        raise SystemExit(f"{plan}: no SLAM job of {model} on {', '.join(sequences)}")
    return jobs


def run_job(out: Path, job: str, overrides: list[str], threshold: float) -> float:
    """The job's median-run ATE RMSE with ``segmenter.threshold=threshold`` (reused if done)."""
    folder = out / "mask_size" / job.removeprefix("slam/")
    control = folder / "control.json"
    metrics = folder / "metrics.json"
    reusable = control.is_file() and metrics.is_file()
    if reusable and json.loads(control.read_text()).get("threshold") == threshold:
        return float(json.loads(metrics.read_text())["ate"]["rmse"])
    cmd = [sys.executable, "-m", "uss_slam.slam_eval.run", *overrides,
           f"segmenter.threshold={threshold}", "progress=false", f"out_dir={folder}"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"{job}: uss-slam failed:\n{done.stderr[-2000:]}")
    control.write_text(json.dumps({"threshold": threshold}))
    return float(json.loads(metrics.read_text())["ate"]["rmse"])


def table(rows: list[dict[str, Any]]) -> str:
    def f(values: Sequence[float | None]) -> str:
        return " / ".join("—" if v is None else f"{v:.2f}" for v in values)

    lines = ["| system, filter | sequence | base, argmax | base, grown | like | grown − base | "
             "grown − like |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        diffs = []
        for other in ("base", "like"):
            d = [g - o for g, o in zip(r["grown"], r[other], strict=True)
                 if g is not None and o is not None]  # fmt: skip
            diffs.append(" / ".join(f"{x:+.2f}" for x in d) + (
                f" (median {statistics.median(d):+.2f})" if d else "—"))  # fmt: skip
        lines.append(f"| {r['system']}, {r['variant']} | {r['sequence']} | {f(r['base'])} | "
                     f"{f(r['grown'])} | {f(r['like'])} | {diffs[0]} | {diffs[1]} |")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--experiment", type=Path, required=True)
    parser.add_argument("--base", default="source_only", help="config of the model to grow")
    parser.add_argument("--like", default="adaptsegnet_n5", help="config whose mask size to match")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--sequences", default="walking_xyz,walking_rpy,static_xyz")
    parser.add_argument("--systems", default="harness,orbslam3")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    out = args.experiment
    seeds = [int(s) for s in args.seeds.split(",")]
    sequences = args.sequences.split(",")
    systems = args.systems.split(",")
    for s in systems:
        if s not in VARIANTS:
            parser.error(f"--systems: unknown system {s!r}; accepted: {', '.join(VARIANTS)}")
    runs_csv = out / "runs.csv"
    if not runs_csv.is_file():
        raise SystemExit(f"{runs_csv}: no runs.csv (expected a uss-experiments output folder)")
    with runs_csv.open(newline="") as fh:
        runs = list(csv.DictReader(fh))
    frames = target_frames(out)
    thresholds, shares = {}, {}
    for seed in seeds:
        paths = {k: out / "exports" / f"{c}_s{seed}" / f"{c}_s{seed}.onnx"
                 for k, c in (("base", args.base), ("like", args.like))}  # fmt: skip
        for p in paths.values():
            if not p.is_file():
                raise SystemExit(f"{p}: no such export")
        wanted = person_share(paths["like"], frames, None)
        t = match_threshold(lambda v, p=paths["base"]: person_share(p, frames, v), wanted)
        thresholds[seed] = t
        shares[seed] = {"like": wanted, "base_argmax": person_share(paths["base"], frames, None),
                        "base_grown": person_share(paths["base"], frames, t)}  # fmt: skip
        print(f"seed {seed}: {args.like} person share {wanted:.3f}; {args.base} "
              f"{shares[seed]['base_argmax']:.3f} at argmax, {shares[seed]['base_grown']:.3f} at "
              f"threshold {t}", file=sys.stderr, flush=True)  # fmt: skip
    ates: dict[str, float] = {}
    for seed in seeds:
        for job, ov in base_jobs(out, f"{args.base}_s{seed}", sequences, systems).items():
            ates[job] = run_job(out, job, ov, thresholds[seed])
            print(f"{job} @ {thresholds[seed]}: ATE {1000 * ates[job]:.1f} mm", file=sys.stderr,
                  flush=True)  # fmt: skip
    rows = []
    for system in systems:
        for variant in VARIANTS[system]:
            for seq in sequences:
                row: dict[str, Any] = {"system": system, "variant": variant, "sequence": seq,
                                       "base": [], "grown": [], "like": []}  # fmt: skip
                key = f"{system}:{variant}"
                for seed in seeds:
                    base, like = f"{args.base}_s{seed}", f"{args.like}_s{seed}"
                    row["base"].append(slam_ratios(runs, seq, base)[key])
                    row["like"].append(slam_ratios(runs, seq, like)[key])
                    grown = ates.get(f"slam/{system}/{seq}/{variant}/{base}")
                    fake = [] if grown is None else [{
                        "kind": "slam", "id": f"slam/{system}/{seq}/{variant}/grown",
                        "status": "ok", "system": system, "sequence": seq, "variant": variant,
                        "ate_rmse": grown}]  # fmt: skip
                    row["grown"].append(slam_ratios([*runs, *fake], seq, "grown")[key])
                if any(v is not None for v in row["grown"]):
                    rows.append(row)
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps({"thresholds": thresholds, "person_share": shares,
                                         "rows": rows}, indent=1))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

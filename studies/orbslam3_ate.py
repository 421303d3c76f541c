"""How does the real ORB-SLAM3 (pyorbslam3), unfiltered and with the ground-truth people blanked,
compare with the harness on the same synthetic frames? An accuracy study, reported in
docs/results/slam.md, "2026-12-01 — ORB-SLAM3 next to the harness (seed 7)".

For each preset: ORB-SLAM3 with ``segmenter=none`` and with ``segmenter=labels`` (person, dilated
as the harness's semantic filter, blanked to grey with depth 0), each the median of ``--repeats``
runs with min / max; then the harness's baseline and ``semantic`` filter (deterministic, one run)
on the same sequence. ATE RMSE through the same evaluation
(``slam_eval.scoring.evaluation.evaluate``: SE(3) Umeyama, 0.02 s association).

    python studies/orbslam3_ate.py --data outputs/bench/orbslam3 --repeats 3

Sequences are rendered into ``--data`` on first use (``uss-synth sequence --preset P --frames 300
--size 640x480 --seed 7``). The vocabulary is built from a *different* sequence (walking_halfsphere,
seed 1, every 5th of 150 frames, k=10, L=4), so ORB-SLAM3 is not evaluated on its training frames.
Each ORB-SLAM3 run's outputs stay in ``--data/runs/<preset>_<segmenter>/``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.scoring.evaluation import EvalConfig, evaluate
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.systems.orbslam3.config import OrbSlam3Config
from uss_slam.slam_eval.systems.orbslam3.system import SequenceSpec, run_orbslam3
from uss_slam.slam_eval.systems.orbslam3.vocabulary import build_from_sequences
from uss_slam.synthetic import render_sequence


def sequence(data: Path, preset: str, frames: int, seed: int) -> Path:
    path = data / f"{preset}_{frames}_seed{seed}"
    if not (path / "rgb.txt").is_file():
        print(f"rendering {path} ...", file=sys.stderr)
        render_sequence(path, preset=preset, frames=frames, size=(640, 480), seed=seed)
    return path


def harness(path: Path, filters: list[str]) -> dict:
    seq = TumSequence(path, load_labels=True)
    result = SlamPipeline(seq, LabelsSegmenter(), build_filters(filters), progress=False).run()
    ev = evaluate(result.trajectory, seq.groundtruth, EvalConfig())
    return {
        "ate_rmse": None if ev.ate is None else ev.ate.stats.rmse,
        "tracked_fraction": result.tracked_fraction,
        "fps": result.fps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("outputs/bench/orbslam3"))
    parser.add_argument("--presets", nargs="+", default=["static_xyz", "walking_xyz"])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--vocabulary", type=Path, help="default: built into --data")
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    args.data.mkdir(parents=True, exist_ok=True)
    vocab = args.vocabulary
    if vocab is None:
        vocab = args.data / "vocab_k10_L4.txt"
        if not vocab.is_file():
            train = sequence(args.data, "walking_halfsphere", 150, 1)
            built = build_from_sequences([train], vocab, k=10, levels=4, stride=5)
            print(
                f"vocabulary {vocab}: {built.words} words from {built.descriptors} descriptors "
                f"of {built.images} frames ({built.cluster_s:.1f} s)",
                file=sys.stderr,
            )
    config = OrbSlam3Config(vocabulary=str(vocab), repeats=args.repeats)
    results: dict[str, dict] = {}
    start = time.perf_counter()
    for preset in args.presets:
        path = sequence(args.data, preset, args.frames, args.seed)
        row: dict[str, dict] = {}
        for name, segmenter in (("none", NoSegmenter()), ("labels", LabelsSegmenter())):
            data = run_orbslam3(
                SequenceSpec(str(path)),
                segmenter,
                [SemanticFilter(["person"], 5)],
                config,
                EvalConfig(),
                args.data / "runs" / f"{preset}_{name}",
                progress=False,
            )
            rep = data["ate_rmse_repeats"]
            row[f"orbslam3_{name}"] = {
                "ate_rmse_median": rep["median"],
                "ate_rmse_min": rep["min"],
                "ate_rmse_max": rep["max"],
                "frames_ok": [r["tracking_states"].get("OK", 0) for r in data["repeats"]],
                "fps": data["fps"],
            }
        row["harness_baseline"] = harness(path, [])
        row["harness_semantic"] = harness(path, ["semantic"])
        results[preset] = row
    elapsed = time.perf_counter() - start

    def cell(v: float | None) -> str:
        return "—" if v is None else f"{v:.4f}"

    print(f"\nATE RMSE [m], {args.frames} frames 640x480 seed {args.seed}; ORB-SLAM3: median of "
          f"{args.repeats} (min-max); harness: one run (deterministic)")  # fmt: skip
    print("| preset | ORB-SLAM3 | ORB-SLAM3 + GT masks blanked | harness | harness + semantic |")
    print("|---|---|---|---|---|")
    for preset, row in results.items():
        o = [row["orbslam3_none"], row["orbslam3_labels"]]
        cells = [f"{cell(x['ate_rmse_median'])} ({cell(x['ate_rmse_min'])}-"
                 f"{cell(x['ate_rmse_max'])})" for x in o]  # fmt: skip
        cells += [
            cell(row["harness_baseline"]["ate_rmse"]),
            cell(row["harness_semantic"]["ate_rmse"]),
        ]
        print(f"| {preset} | " + " | ".join(cells) + " |")
    print(f"\n({elapsed:.0f} s; frames OK per repeat: " + "; ".join(
        f"{p} {k[9:]} {v['frames_ok']}" for p, row in results.items() for k, v in row.items()
        if k.startswith("orbslam3")) + ")")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()

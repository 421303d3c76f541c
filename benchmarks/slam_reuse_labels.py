"""What does ``slam.reuse_labels`` save? One ``uss-slam`` job of ``uss-experiments`` (an exported
segmenter, the ``semantic`` filter, ``slam.repeats=3``) timed with the segmenter run in every repeat
and with repeat 0's labels reused, alternately, in the same command. Reported in BENCHMARKS.md,
"Repeated harness runs: segmenting once (``slam.reuse_labels``)".

Each job is a fresh ``python -m uss_slam.slam_eval.run`` process, as the experiments launch them
(start-up, model loading and the report included). Reported: median wall and CPU seconds per
job (CPU = user + system time of the process and its threads), their ratio reused / not, and
whether every repeat's ATE RMSE is the same both ways (it must be: the labels are the same).

    python benchmarks/slam_reuse_labels.py --sequence SEQ --model MODEL.onnx --runs 3
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from uss_slam.testing.machine import cpu_model


def one_job(args: argparse.Namespace, reuse: bool, out: Path) -> tuple[float, float, list]:
    """(wall s, CPU s, per-repeat ATE RMSE) of one ``uss-slam`` job."""
    command = [
        sys.executable, "-m", "uss_slam.slam_eval.run",
        f"sequence.path={args.sequence}", "segmenter=onnx", f"segmenter.path={args.model}",
        f"filters=[{','.join(args.filters)}]", f"slam.repeats={args.repeats}",
        f"slam.reuse_labels={str(reuse).lower()}", f"out_dir={out}", "progress=false",
    ]  # fmt: skip
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"uss-slam failed ({' '.join(command)}):\n{done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    metrics = json.loads((out / "metrics.json").read_text())
    return wall, cpu, [r["ate_rmse"] for r in metrics["repeats"]]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0].replace("\n", " "),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--sequence", type=Path, required=True, help="a TUM-format sequence")
    parser.add_argument("--model", type=Path, required=True, help="an uss-export .onnx model")
    parser.add_argument("--filters", nargs="+", default=["semantic"], help="uss-slam filters")
    parser.add_argument("--repeats", type=int, default=3, help="slam.repeats of each job")
    parser.add_argument("--runs", type=int, default=3, help="jobs per setting (median)")
    args = parser.parse_args()
    for path in (args.sequence, args.model):
        if not path.exists():
            parser.error(f"{path}: not found")
    times: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    ates: dict[bool, list] = {}
    print(f"{cpu_model()}, {os.cpu_count()} cores; load before: {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            order = (False, True) if i % 2 == 0 else (True, False)
            for reuse in order:
                wall, cpu, ate = one_job(args, reuse, Path(tmp) / f"{reuse}_{i}")
                times[reuse].append((wall, cpu))
                ates.setdefault(reuse, ate)
                print(
                    f"  run {i} reuse_labels={str(reuse).lower():5s}: {wall:6.1f} s wall, "
                    f"{cpu:6.1f} s CPU (load {os.getloadavg()[0]:.2f})",
                    flush=True,
                )
    med = {
        r: (statistics.median(w for w, _ in t), statistics.median(c for _, c in t))
        for r, t in times.items()
    }
    print(f"\n| slam.reuse_labels | wall [s] (median of {args.runs}) | CPU [s] |")
    print("|---|---|---|")
    for reuse in (False, True):
        print(f"| {str(reuse).lower()} | {med[reuse][0]:.1f} | {med[reuse][1]:.1f} |")
    print(
        f"| ratio true / false | {med[True][0] / med[False][0]:.2f} | "
        f"{med[True][1] / med[False][1]:.2f} |"
    )
    same = ates[True] == ates[False]
    print(f"\nEvery repeat's ATE RMSE the same both ways: {'yes' if same else 'NO'} {ates[True]}")
    if not same:
        raise SystemExit(f"the repeats differ: {ates[False]} without reuse")


if __name__ == "__main__":
    main()

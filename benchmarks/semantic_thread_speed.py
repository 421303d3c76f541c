"""How fast does ``uss-slam`` track with the paper's network segmenting keyframes in the semantic
thread (``segment=thread``), on two cores? Reported in BENCHMARKS.md, "The semantic thread with
the real network".

The network is the paper's DeepLab-v2 on ResNet-101, random weights from the project's own
initialisation (latency does not depend on the weights; nothing is downloaded), exported with
``uss-export``'s :func:`export_segmenter` and quantised to static INT8 as ``uss-export int8=true``
does it (:func:`quantize_int8`); both models are kept in ``--work`` and reused by later calls.
``--model`` runs an exported model of yours instead (the tests use a tiny one).

Per sequence and repeat, three ``uss-slam`` runs as a user starts them (the defaults: local BA,
loop closing, ``slam.prefetch_mode=auto``; ``filters=[semantic] segment=thread slam.repeats=1``):

- ``network``: ``segmenter=onnx segmenter.path=MODEL segmenter.threads=--threads``: onnxruntime
  really runs the network in the semantic thread, beside tracking, on the same cores, and the
  mask it delivers is the frame's ground truth (:func:`uss_slam_with_truth`: the masks a trained
  network would give, so that the map, keyframes and back end match the oracle's);
- ``oracle``: ``segmenter=labels segmenter.latency_s=L segmenter.wait=true`` with ``L`` the
  ``network`` run's measured latency (the mean wall time of its segmentations in the thread):
  the same waits, spending no CPU (the figure the record had so far); right after ``network``;
- ``network labels``: as ``network`` with the random network's own labels (``uss-slam``
  unchanged; its masks are not people, so its map and keyframes differ).

With ``--nice N`` a fourth run, ``network nice``: as ``network`` with ``slam.semantic_nice=N``
(the semantic thread N nice levels below tracking: the network gets the CPU time tracking
leaves).

Reported per run: frames/s end to end (``metrics.json`` ``fps``: the first keyframe's mask,
waited for, included) and after that wait (``tracking``); the CPU ms per frame of tracking (every
``cpu_ms`` row but the first mask's ``segmentation``: reading and ORB in the prefetch, the main
thread's modules) and of the main thread alone; for ``network`` and ``network nice`` the
network's CPU per frame and per call (its thread's CPU clock); masks delivered, the network's
latency (the first, waited-for mask; the mean in the thread) and the keypoints the semantic
filter flagged. Then medians per sequence and cell, the CPU model and the load average.

    python benchmarks/semantic_thread_speed.py --repeats 3 \\
        --sequence SEQ [SEQ ...]      # default: walking_xyz, seed 0, 300 frames, 640x480
    python benchmarks/semantic_thread_speed.py --build-only   # the INT8 model alone (~1 min)

``--set KEY=VALUE ...`` adds ``uss-slam`` overrides to every run (e.g. a local BA setting,
timed against the same command without it; give each its own ``--work``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2

from uss_slam.testing.machine import benchmark_metadata, cpu_model

USS_SLAM = str(Path(sys.executable).with_name("uss-slam"))

MAIN_EXCLUDED = {"read", "orb", "segmentation", "load"}
"""``cpu_ms`` rows that are not the main thread's tracking work: the prefetch's reading and ORB
extraction, and ``segmentation`` (the first keyframe's mask, waited for once)."""


def build_network(work: Path, calibration: Path, backbone: str = "resnet101") -> Path:
    """``work/<backbone>.int8.onnx`` (built once: random net, verified export, static INT8
    calibrated on 4 frames of ``calibration`` at 320x240); returns its path."""
    int8 = work / f"{backbone}.int8.onnx"
    if int8.is_file():
        return int8
    import torch  # only to build the model
    from segmenter_speed import random_net

    from uss_slam.export import export_segmenter, quantize_int8, read_calibration_frames

    work.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(2)
    start = time.perf_counter()
    metadata = benchmark_metadata(backbone)
    # A random ResNet-101's logits reach the hundreds: 1e-2 absolute is ~1e-5 relative.
    fp32 = export_segmenter(random_net(backbone), work / f"{backbone}.onnx", metadata,
                            max_logit_diff=1e-2).path  # fmt: skip
    calib, evaluation = read_calibration_frames(calibration, frames=4)
    small = [cv2.resize(f, (320, 240), interpolation=cv2.INTER_AREA) for f in calib + evaluation]
    q = quantize_int8(fp32, int8, small[:4], small[4:], threads=2, repeats=1)
    print(f"built {int8} in {time.perf_counter() - start:.0f} s (INT8 label agreement with "
          f"FP32 {q['label_agreement_vs_fp32']:.3f})", flush=True)  # fmt: skip
    return int8


def run(seq: Path, out: Path, overrides: list[str], truth: bool = False) -> dict:
    """One ``uss-slam`` run on ``seq`` (``segment=thread``, ``filters=[semantic]``, one repeat)
    with ``overrides`` (``truth``: through :func:`uss_slam_with_truth`); its figures (module
    docstring)."""
    prog = [sys.executable, str(Path(__file__).resolve()), TRUTH] if truth else [USS_SLAM]
    cmd = [
        *prog, f"sequence.path={seq}", "filters=[semantic]", "segment=thread",
        "slam.repeats=1", "progress=false", f"out_dir={out}", f"hydra.run.dir={out}", *overrides,
    ]  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    spent = out.parent / f"{out.name}.network_cpu.json"
    spent.unlink(missing_ok=True)
    env = {**os.environ, NETWORK_CPU: str(spent)}
    load = os.getloadavg()[0]
    done = subprocess.run(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env
    )
    if done.returncode != 0:
        raise SystemExit(f"uss-slam failed ({done.returncode}): {' '.join(cmd)}\n"
                         f"{done.stderr.strip()[-800:]}")  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    thread = m["segmentation"]["semantic_thread"]
    n = max(m["frames"], 1)
    first = float(thread["first_wait_s"])
    network = json.loads(spent.read_text()) if spent.is_file() else None
    return {
        "fps": m["fps"],
        "tracking_fps": (n - 1) / max(m["wall_time_s"] - first, 1e-9),
        "main_cpu_ms": sum(v for k, v in m["cpu_ms"].items() if k not in MAIN_EXCLUDED),
        "tracking_cpu_ms": sum(v for k, v in m["cpu_ms"].items() if k not in ("segmentation",)),
        "network_cpu_s": None if network is None else network["cpu_s"] / max(network["calls"], 1),
        "network_cpu_ms": None if network is None else 1000.0 * network["cpu_s"] / n,
        "masks": m["segmentation"]["frames_segmented"],
        "requested": thread["requested"],
        "first_s": first,
        "latency_s": float(thread["mean_segment_s"]),
        "flagged": m["keypoints"].get("flagged.semantic", m["keypoints"].get("flagged", {})),
        "tracked": m["tracked_fraction"],
        "ate": (m["ate"] or {}).get("rmse", float("nan")),  # None: too few frames tracked
        "keyframes": m["keyframes"],
        "load": [load, os.getloadavg()[0]],
        "cpu_ms": m["cpu_ms"],
    }


TRUTH = "--uss-slam-with-truth"
NETWORK_CPU = "USS_BENCH_NETWORK_CPU"
"""Environment variable: where :func:`uss_slam_with_truth` writes the network's calls and their
CPU and wall seconds (its own thread's CPU clock: onnxruntime with one intra-op thread computes
in the caller)."""


def uss_slam_with_truth() -> None:
    """``uss-slam`` (the arguments after :data:`TRUTH`) with one change: the ONNX segmenter runs
    the network on every frame asked of it, as always, then returns the frame's ground-truth
    labels instead of its own (the sequence's ``labels/`` are read): the network's cost in the
    loop with the masks a trained network would give."""
    from uss_slam.slam_eval import run as uss_slam_run
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    infer = OnnxSegmenter.infer
    spent = {"calls": 0, "cpu_s": 0.0, "wall_s": 0.0}

    def segment(self: OnnxSegmenter, frame):  # noqa: ANN001, ANN202
        wall, cpu = time.perf_counter(), time.thread_time()
        infer(self, frame.rgb)
        spent["cpu_s"] += time.thread_time() - cpu
        spent["wall_s"] += time.perf_counter() - wall
        spent["calls"] += 1
        return frame.labels

    OnnxSegmenter.segment = segment
    OnnxSegmenter.needs_labels = True
    sys.argv = ["uss-slam", *sys.argv[2:]]
    record = os.environ.get(NETWORK_CPU)
    try:
        uss_slam_run.main()
    finally:
        if record:
            Path(record).write_text(json.dumps(spent))


def measured(net: dict) -> float:
    """The network's latency (s) the oracle is given: the mean of its segmentations in the
    thread, or the first (waited-for) mask's when the thread delivered none."""
    return net["latency_s"] if net["masks"] > 1 else net["first_s"]


def show(name: str, seq: str, repeat: int, r: dict) -> None:
    net = "" if r["network_cpu_s"] is None else (
        f", network {r['network_cpu_ms']:.1f} ({r['network_cpu_s']:.2f} CPU s per call)"
    )  # fmt: skip
    print(
        f"{seq} repeat {repeat} [{name}]: {r['fps']:.1f} frames/s end to end, tracking "
        f"{r['tracking_fps']:.1f} frames/s; CPU ms/frame: tracking {r['tracking_cpu_ms']:.1f} "
        f"(main thread {r['main_cpu_ms']:.1f}){net}; masks {r['masks']} of "
        f"{r['requested'] + 1} asked; latency first {r['first_s']:.2f} s, in the thread "
        f"{r['latency_s']:.2f} s; flagged {r['flagged']}; tracked {r['tracked']:.2f}, ATE "
        f"{r['ate']:.4f} m, {r['keyframes']} kf; load {r['load'][0]:.1f} -> {r['load'][1]:.1f}",
        flush=True,
    )


def summary(runs: dict[str, dict[str, list[dict]]]) -> None:
    """Medians per sequence and cell, as a markdown table."""
    keys = ("fps", "tracking_fps", "tracking_cpu_ms", "main_cpu_ms", "masks", "latency_s")
    print("\n| sequence | run | frames/s | tracking frames/s | tracking CPU ms/frame (main "
          "thread) | network CPU ms/frame (s per mask) | masks | latency s (first; thread) "
          "| load |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for seq, cells in runs.items():
        for name, done in cells.items():
            if not done:
                continue
            med = {k: statistics.median(r[k] for r in done) for k in (*keys, "first_s")}
            nets = [r for r in done if r["network_cpu_s"] is not None]
            net = "—" if not nets else (
                f"{statistics.median(r['network_cpu_ms'] for r in nets):.1f} "
                f"({statistics.median(r['network_cpu_s'] for r in nets):.2f})"
            )  # fmt: skip
            loads = [v for r in done for v in r["load"]]
            print(f"| {seq} | {name} | {med['fps']:.1f} | {med['tracking_fps']:.1f} | "
                  f"{med['tracking_cpu_ms']:.1f} ({med['main_cpu_ms']:.1f}) | {net} | "
                  f"{med['masks']:g} | {med['first_s']:.2f}; {med['latency_s']:.2f} | "
                  f"{min(loads):.1f}–{max(loads):.1f} |")  # fmt: skip


CELLS = ("network", "oracle", "network labels")
"""The runs of each repeat (module docstring); with ``--nice N`` also ``network nice``."""


def main() -> None:
    if sys.argv[1:2] == [TRUTH]:
        uss_slam_with_truth()
        return
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0].replace("\n", " "),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--sequence", type=Path, nargs="+",
                        help="TUM sequence folders with labels/ (default: walking_xyz seed 0, "
                             "rendered into --data on first use)")  # fmt: skip
    parser.add_argument("--data", type=Path, default=Path("outputs/bench/slam"))
    parser.add_argument("--model", type=Path, help="an exported .onnx (default: build the INT8 "
                        "ResNet-101 DeepLab-v2 in --work)")  # fmt: skip
    parser.add_argument("--backbone", default="resnet101", choices=("resnet101", "resnet_small"),
                        help="the DeepLab-v2 backbone built without --model (resnet_small: the "
                             "demo's, for a quick check)")  # fmt: skip
    parser.add_argument("--work", type=Path, default=Path("outputs/bench/semantic_thread"))
    parser.add_argument("--threads", type=int, default=1, help="segmenter.threads")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--nice", type=int, default=0, choices=range(20), metavar="0..19",
                        help="also run the network cell with slam.semantic_nice=N")  # fmt: skip
    parser.add_argument("--build-only", action="store_true", help="build the model and stop")
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                        help="uss-slam overrides of every run (a setting timed against the "
                             "same command without it)")  # fmt: skip
    args = parser.parse_args()
    bad = [o for o in args.set if "=" not in o]
    if bad:
        parser.error(f"--set: expected KEY=VALUE, got {bad[0]!r}")
    for path in [*(args.sequence or []), *([args.model] if args.model else [])]:
        if not path.exists():
            parser.error(f"{path}: not found")
    if args.repeats < 1 or args.threads < 1:
        parser.error("--repeats and --threads: expected integers >= 1")
    sequences = args.sequence
    if not sequences:
        from uss_slam.testing.harness_runs import sequence_path

        sequences = [sequence_path(args.data, "walking_xyz", 300, (640, 480), 0)]
    print(f"{os.cpu_count()} CPUs ({cpu_model()}), load average {os.getloadavg()[0]:.2f}",
          flush=True)  # fmt: skip
    model = args.model or build_network(args.work, sequences[0], args.backbone)
    if args.build_only:
        return
    network = ["segmenter=onnx", f"segmenter.path={model.resolve()}",
               f"segmenter.threads={args.threads}"]  # fmt: skip
    runs: dict[str, dict[str, list[dict]]] = {}
    for seq in sequences:
        names = (*CELLS, "network nice") if args.nice else CELLS
        cells = runs.setdefault(seq.name, {name: [] for name in names})
        for repeat in range(args.repeats):
            # The oracle right after the network, at the latency that run measured (same,
            # ground-truth masks); the network's own labels last in even repeats, first in odd.
            order = names if repeat % 2 == 0 else (*names[2:][::-1], *names[:2])
            for name in order:
                if name == "oracle":
                    latency = measured(cells["network"][-1])
                    overrides = ["segmenter=labels", f"segmenter.latency_s={latency:.3f}",
                                 "segmenter.wait=true"]  # fmt: skip
                elif name == "network nice":
                    overrides = [*network, f"slam.semantic_nice={args.nice}"]
                else:
                    overrides = network
                out = args.work / "runs" / seq.name / str(repeat) / name.replace(" ", "_")
                truth = name in ("network", "network nice")
                cells[name].append(run(seq, out, [*overrides, *args.set], truth=truth))
                show(name, seq.name, repeat, cells[name][-1])
    summary(runs)
    (args.work / "runs.json").write_text(json.dumps(runs, indent=1) + "\n")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

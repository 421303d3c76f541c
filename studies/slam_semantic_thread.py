"""What does segmenting keyframes in a semantic thread, at a slow network's latency, cost in ATE
against masks on every frame? Recorded in docs/results/slam.md ("The semantic thread").

Per sequence, ``uss-slam`` (the harness, its defaults: local BA and loop closing on) with
``segmenter=labels filters=[semantic]`` and ``slam.repeats`` repeats, in these cells:

- ``per-frame``: ``segment=every_frame`` (ground-truth masks on every frame, the reference);
- ``thread L s``: ``segment=thread segmenter.latency_s=L`` for each ``--latency`` (the oracle's
  masks, each delivered ``L`` s of camera time after its keyframe asked: deterministic);
- with ``--baseline``: ``filters=[]`` (no filter), to show how much error there is to remove.

With ``--orbslam3 VOCAB`` the same cells run ORB-SLAM3 (``system=orbslam3``, that vocabulary,
``system.repeats``): masks on every frame blanked in its input, against ``segment=thread``'s
masks every ``L`` s carried by its own tracked poses (``slam_eval/systems/orbslam3/thread.py``).

Prints one table row per sequence and cell (median ATE RMSE of the repeats with min-max, the
ratio of the median to the per-frame cell's, the tracked share of frames beside the per-frame
cell's, frames/s of the timing repeat, masks delivered, the load)
and writes every cell's figures to ``OUT/cells.json``; each run's folder is ``OUT/<sequence>/
<cell>``. A sequence without ``labels/`` (the real TUM stretches, no people) needs one of zeros
(``--zero-labels`` writes a copy of symlinks plus an all-zero ``labels/`` under ``OUT``).

    python studies/slam_semantic_thread.py SEQ [SEQ ...] --out outputs/sem/study \\
        --latency 2.9 0.5 --repeats 5

``--set KEY=VALUE ...`` gives every harness cell the same ``uss-slam`` overrides (a candidate
setting judged against the same command without it); ``--thread-set`` the thread cells only,
and with ``--label NAME`` their cells are named ``thread L s NAME``, so that a candidate's
thread cells join today's in the same ``--out`` (the per-frame cells already there are not run
again). ``studies/slam_thread_rule.py`` reads ``cells.json`` and applies a pre-registered rule.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

USS_SLAM = str(Path(sys.executable).with_name("uss-slam"))


def zero_labelled(seq: Path, out: Path) -> Path:
    """``out/<name>``: symlinks to ``seq``'s files and an all-zero ``labels/`` (no people)."""
    dst = out / "zero_labelled" / seq.name
    (dst / "labels").mkdir(parents=True, exist_ok=True)
    for entry in seq.iterdir():
        if entry.name != "labels" and not (dst / entry.name).exists():
            os.symlink(entry.resolve(), dst / entry.name)
    for image in sorted((seq / "rgb").iterdir()):
        target = dst / "labels" / image.name
        if not target.exists():
            h, w = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE).shape
            cv2.imwrite(str(target), np.zeros((h, w), np.uint8))
    return dst


def cells(
    latencies: list[float], baseline: bool, thread_set: list[str] | None = None, label: str = ""
) -> list[tuple[str, list[str]]]:
    """``(cell name, uss-slam overrides)`` in the order they run; ``thread_set``: overrides of
    the thread cells only (``--thread-set``), whose names end in `` label`` if given."""
    out = [("per-frame", ["segment=every_frame", "filters=[semantic]"])]
    out += [
        (
            f"thread {lat:g} s" + (f" {label}" if label else ""),
            ["segment=thread", f"segmenter.latency_s={lat}", "filters=[semantic]"]
            + list(thread_set or []),
        )
        for lat in latencies
    ]
    if baseline:
        out.append(("no filter", ["segment=every_frame", "filters=[]"]))
    return out


def run_cell(
    seq: Path, folder: Path, overrides: list[str], repeats: int, vocab: Path | None = None
) -> dict:
    """One ``uss-slam`` call (with ``vocab``: ``system=orbslam3`` and that vocabulary); the
    cell's figures from its ``metrics.json``."""
    system = (
        [f"slam.repeats={repeats}"]
        if vocab is None
        else ["system=orbslam3", f"system.vocabulary={vocab}", f"system.repeats={repeats}"]
    )
    # ORB-SLAM3 refuses filters=[] with a segmenter (it would still blank the semantic
    # filter's pixels): unfiltered is segmenter=none there
    unfiltered = vocab is not None and "filters=[]" in overrides
    segmenter = "segmenter=none" if unfiltered else "segmenter=labels"
    cmd = [
        USS_SLAM, f"sequence.path={seq}", segmenter, *system,
        f"out_dir={folder}", f"hydra.run.dir={folder}", "progress=false", *overrides,
    ]  # fmt: skip
    start = time.time()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    m = json.loads((folder / "metrics.json").read_text())
    spread = m.get("ate_rmse_repeats") or {"median": m["ate"]["rmse"], "min": None, "max": None}
    seg = m.get("segmentation") or _orbslam3_masks(m)
    return {
        "command": " ".join(cmd[1:]),
        "ate_median": spread["median"],
        "ate_min": spread["min"],
        "ate_max": spread["max"],
        "ate_repeats": [r["ate_rmse"] for r in m.get("repeats", [])],
        "tracked_fraction": m["tracked_fraction"],
        "tracked_repeats": [r["tracked_fraction"] for r in m.get("repeats", [])],
        "fps": m["fps"],
        "masks": seg["frames_segmented"],
        "semantic_thread": seg.get("semantic_thread"),
        "wall_s": time.time() - start,
        "load": os.getloadavg()[0],
    }


def _orbslam3_masks(m: dict) -> dict:
    """An ORB-SLAM3 run's masks: none unfiltered, every frame's, or with the thread those
    delivered in its median repeat."""
    thread = m.get("semantic_thread")
    if m.get("blanked") is None:
        count = 0
    elif thread is None:
        count = m["frames"]
    else:
        count = thread["delivered"][m["median_repeat"]]
    return {"frames_segmented": count, "semantic_thread": thread}


def row(sequence: str, name: str, cell: dict, reference: dict) -> str:
    """One table row: median ATE (min–max) of ``cell``, its ratio to the ``reference``
    (per-frame) median, the tracked share of frames of both (of the median-ATE repeat; with
    several repeats also the cell's lowest repeat's: a cell that loses the frames its reference
    tracks may show a lower ATE for it), frames/s, masks delivered and the load."""
    c = cell
    span = "" if c["ate_min"] is None else f" ({c['ate_min']:.4f}–{c['ate_max']:.4f})"
    repeats = c.get("tracked_repeats") or []
    lowest = f"; lowest repeat {100 * min(repeats):.1f}%" if len(repeats) > 1 else ""
    return (
        f"| {sequence} | {name} | {c['ate_median']:.4f}{span} | "
        f"×{c['ate_median'] / reference['ate_median']:.2f} | "
        f"{100 * c['tracked_fraction']:.1f}% (per-frame {100 * reference['tracked_fraction']:.1f}%"
        f"{lowest}) | {c['fps']:.1f} | {c['masks']} | {c['load']:.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", type=Path, nargs="+")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--latency", type=float, nargs="+", default=[2.9, 0.5])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline", action="store_true", help="also the unfiltered cell")
    parser.add_argument("--zero-labels", action="store_true", help="sequences without people")
    parser.add_argument(
        "--orbslam3", type=Path, metavar="VOCAB", help="run ORB-SLAM3 with this vocabulary"
    )
    parser.add_argument(
        "--thread-set", nargs="+", default=[], metavar="KEY=VALUE",
        help="uss-slam overrides of the thread cells only (e.g. slam.provisional_points=true)",
    )  # fmt: skip
    parser.add_argument(
        "--label", default="", help="a name for the thread cells (a candidate's, beside today's)"
    )
    parser.add_argument(
        "--set", nargs="+", default=[], metavar="KEY=VALUE",
        help="uss-slam overrides of every harness cell (a candidate setting)",
    )  # fmt: skip
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    record = args.out / "cells.json"
    done = json.loads(record.read_text()) if record.exists() else {}
    for seq in args.sequences:
        path = zero_labelled(seq, args.out) if args.zero_labels else seq
        rows = done.setdefault(seq.name, {})
        for name, overrides in cells(args.latency, args.baseline, args.thread_set, args.label):
            if name not in rows:
                folder = args.out / seq.name / name.replace(" ", "_")
                overrides = overrides + ([] if args.orbslam3 else args.set)
                rows[name] = run_cell(path, folder, overrides, args.repeats, args.orbslam3)
                record.write_text(json.dumps(done, indent=1))
            print(row(seq.name, name, rows[name], rows["per-frame"]), flush=True)


if __name__ == "__main__":
    main()

"""The training memory estimate (``train/memory.py``) beside the measured peak, for settings
users run: each training runs as ``uss-train`` in its own process tree, sampled every 0.1 s.

- **estimate**: what the run itself logged before its first batch (``memory estimate: N bytes
  beyond the H held now``): the bytes it holds at that point plus the estimate for the rest;
- **peak PSS**: the largest sum, over the process and its data-loading workers, of their
  proportional set sizes (``/proc/PID/smaps_rollup``: pages shared between the processes
  counted once), sampled every 0.1 s;
- **peak RSS**: the main process's high-water mark (``VmHWM`` of ``/proc/PID/status``, sampled
  with the rest: the figure ``/usr/bin/time -v`` prints, the workers' own pages not included;
  ``ru_maxrss`` (``os.wait4``) is kept beside it: on Linux it also counts the parent's pages
  at the fork, a few MB from this script, hundreds from a test process holding torch).

    nice python studies/memory_peaks.py --voc VOC2012 --seq SEQ --seq640 SEQ640 \\
        --out /tmp/memory_peaks [--tum TUM --onnx M --vocab V] [--only ci,demo]

Writes ``OUT/results.json`` and prints one line per setting.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent
ESTIMATE = re.compile(r"memory estimate: (\d+) bytes beyond the (\d+) held now")

SETTINGS: dict[str, str] = {
    # uss-slam (the harness) on the real 640x480 frames: defaults; 256 frames read ahead; the
    # small exported segmenter (its arena, 4 threads) with 3 repeats keeping its labels
    "slam": "uss-slam sequence.path={tum} progress=false",
    "slam-50": "uss-slam sequence.path={tum} progress=false sequence.max_frames=50",
    "slam-prefetch": "uss-slam sequence.path={tum} progress=false slam.prefetch=256 slam.workers=4",
    "slam-onnx": "uss-slam sequence.path={tum} progress=false segmenter=onnx "
    "segmenter.path={onnx} segmenter.threads=4 filters=[semantic] slam.repeats=3",
    "slam-process": "uss-slam sequence.path={tum} progress=false slam.prefetch_mode=process "
    "'compare=[[flow],[geometry]]'",
    # ORB-SLAM3 (its worker process, the vocabulary, its map), its 3 repeats one after another
    "slam-orbslam3": "uss-slam sequence.path={tum} progress=false system=orbslam3 "
    "system.vocabulary={vocab}",
    # the CI smoke run: small DeepLab, batch 2, 129 px crops
    "ci": "experiment=ci data.source.root={voc} data.target.roots=[{seq}] data.val.roots=[{seq}]",
    # uss-demo's adapted training (batch 4, 129 px, one worker, precise BN), 4 iterations
    "demo": "experiment=demo data.source.root={voc} data.target.roots=[{seq}] "
    "data.val.roots=[{seq}] model.max_iters=4 data.iterations_per_epoch=2 "
    "callbacks.precise_bn.images=8",
    # scale=standard's trainings (AdaptSegNet at the paper's depth 5 on 320x240 data, the
    # overrides uss-experiments passes), 4 iterations
    "standard": "experiment=demo model/method=adaptsegnet model.method.discriminator.n_layers=5 "
    "data.source.root={voc} data.target.roots=[{seq}] data.val.roots=[{seq}] model.max_iters=4 "
    "data.iterations_per_epoch=2 callbacks.image_logger=null ++trainer.enable_progress_bar=false",
    # a larger batch and crop, two workers, validation on whole 640x480 frames
    # the paper's network (DeepLab-v2 ResNet-101) at 321 px crops, 2 iterations
    "paper-net": "experiment=ci model/net=deeplab_resnet101 data.batch_size=2 "
    "data.source.transform.crop_size=321 data.target.transform.crop_size=321 "
    "data.source.root={voc} data.target.roots=[{seq}] data.val.roots=[{seq}] model.max_iters=2",
    "large": "experiment=demo model/method=adaptsegnet data.batch_size=8 "
    "data.source.transform.crop_size=321 data.target.transform.crop_size=321 "
    "data.num_workers=2 data.source.root={voc} data.target.roots=[{seq}] "
    "data.val.roots=[{seq640}] model.max_iters=2 data.iterations_per_epoch=2 "
    "callbacks.precise_bn.images=8",
}


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (``/proc/PID/task/TID/children``)."""
    found, todo = [], [pid]
    while todo:
        p = todo.pop()
        found.append(p)
        for task in Path(f"/proc/{p}/task").glob("*"):
            with contextlib.suppress(OSError, ValueError):  # gone meanwhile
                todo += [int(c) for c in (task / "children").read_text().split()]
    return found


def _pss(pid: int) -> int:
    """Proportional set size of ``pid`` in bytes (0 once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        return 0
    return 0


def _status_bytes(pid: int, name: str) -> int:
    """A ``Vm*`` row of ``/proc/PID/status`` in bytes (0 once the process is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{name}:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        return 0
    return 0


def measure(name: str, overrides: str, out: Path) -> dict[str, object]:
    """Run one setting; its estimate, peaks, exit code and seconds."""
    run = out / name
    words = shlex.split(overrides)
    if words[0] == "uss-slam":
        # its estimate is a DEBUG line (at INFO it would reach an earlier run's log before
        # the run is known to go ahead): ask Hydra for that logger's DEBUG lines
        argv = [str(BIN / "uss-slam"), *words[1:], f"out_dir={run}",
                "hydra.verbose=uss_slam.slam_eval.run"]  # fmt: skip
    else:
        argv = [str(BIN / "uss-train"), *words, f"hydra.run.dir={run}",
                f"paths.log_dir={out / 'logs'}", "logger=none"]  # fmt: skip
    start = time.perf_counter()
    with open(out / f"{name}.output", "w") as err:
        proc = subprocess.Popen(argv, stdout=err, stderr=subprocess.STDOUT)
        peak = hwm = 0
        while True:
            done, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if done:
                break
            peak = max(peak, sum(_pss(p) for p in _tree(proc.pid)))
            hwm = max(hwm, _status_bytes(proc.pid, "VmHWM"))
            time.sleep(0.1)
    log = "\n".join(p.read_text() for p in [*run.glob("*.log"), out / f"{name}.output"])
    found = ESTIMATE.search(log)
    need, held = (int(found.group(1)), int(found.group(2))) if found else (0, 0)
    return {
        "setting": name, "overrides": overrides, "exit": os.waitstatus_to_exitcode(status),
        "seconds": round(time.perf_counter() - start, 1), "held_at_check": held,
        "estimate": held + need, "peak_pss": peak, "peak_rss_main": hwm,
        "ru_maxrss": usage.ru_maxrss * 1024,
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--voc", required=True, help="a VOC2012 folder (uss-synth voc)")
    parser.add_argument("--seq", required=True, help="a labelled sequence (uss-synth sequence)")
    parser.add_argument("--seq640", required=True, help="a labelled 640x480 sequence")
    parser.add_argument("--tum", default="", help="a real TUM sequence (uss-slam settings)")
    parser.add_argument("--onnx", default="", help="an exported segmenter (uss-export)")
    parser.add_argument("--vocab", default="", help="an ORB vocabulary (uss-vocab build)")
    parser.add_argument("--out", type=Path, default=Path("outputs/memory_peaks"))
    parser.add_argument("--only", default="", help="comma-separated setting names")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    names = args.only.split(",") if args.only else list(SETTINGS)
    rows = []
    for name in names:
        paths = {"voc": args.voc, "seq": args.seq, "seq640": args.seq640, "tum": args.tum}
        text = SETTINGS[name].format(**paths, onnx=args.onnx, vocab=args.vocab)
        row = measure(name, text, args.out.resolve())
        rows.append(row)
        print(f"{name:9} exit {row['exit']} {row['seconds']:6.1f} s  estimate "
              f"{row['estimate'] / 1e9:.2f} GB  peak PSS {row['peak_pss'] / 1e9:.2f} GB  "
              f"peak RSS (main) {row['peak_rss_main'] / 1e9:.2f} GB", flush=True)  # fmt: skip
    (args.out / "results.json").write_text(json.dumps({
        "load_before": os.getloadavg()[0], "rows": rows}, indent=1) + "\n")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""One ORB-SLAM3 repeat in a fresh Python process (ORB-SLAM3 keeps the first camera it saw in
static members and ends the process on some errors): :func:`run_worker` starts
``python -m uss_slam.slam_eval.systems.orbslam3.worker JOB.json`` and reads back its states and
times; :func:`work` is what that process runs.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.errors import UssSlamError

from ...sequence import TumSequence
from .masking import blank_dynamic, read_filled


@dataclass(frozen=True)
class Job:
    """What a worker process needs (written as JSON)."""

    sequence: dict[str, Any]
    vocabulary: str
    settings: str
    depth_factor: float
    rgb: bool
    masks: str | None
    blank_value: int
    filled: str | None
    """The folder of the inpainted frames (``system.blank_fill=inpaint``), or None (grey)."""
    realtime: bool
    trajectory: str
    result: str
    thread: dict[str, Any] | None = None
    """``segment=thread`` (:mod:`.thread`): ``labels`` (the ``.npz`` of the segmented frames),
    ``segmented`` / ``delivered`` / ``latency_s`` (the schedule), ``k`` (3x3 camera matrix),
    ``filters`` and ``filter_params`` (the filters whose pixels are blanked); None: ``masks``."""


def run_worker(job: Job, log_path: Path, workdir: Path, index: int) -> dict[str, Any]:
    """Run one repeat in a fresh Python process; its console output goes to ``log_path``."""
    job_path = workdir / f"job_{index}.json"
    job_path.write_text(json.dumps(asdict(job)), encoding="utf-8")
    with open(log_path, "wb") as log_file:
        proc = subprocess.run(
            [sys.executable, "-m", "uss_slam.slam_eval.systems.orbslam3.worker", str(job_path)],
            stdout=log_file,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            check=False,
        )
    result_path = Path(job.result)
    if proc.returncode != 0 or not result_path.is_file():
        tail = _last_line(log_path)
        how = (
            f"was killed by signal {-proc.returncode}"
            if proc.returncode < 0
            else f"exited with code {proc.returncode}"
        )
        raise UssSlamError(f"ORB-SLAM3 {how} in repeat {index} (log {log_path}): {tail}")
    return json.loads(result_path.read_text(encoding="utf-8"))


def _last_line(path: Path) -> str:
    try:
        lines = [
            ln.strip()
            for ln in path.read_text(encoding="utf-8", errors="replace").splitlines()
            if ln.strip()
        ]
    except OSError:
        return "no log"
    return lines[-1][:200] if lines else "no output"


def work(job_path: str) -> None:
    """The worker process: feed every frame to ORB-SLAM3, save its trajectory and states."""
    job = Job(**json.loads(Path(job_path).read_text(encoding="utf-8")))
    import pyorbslam3

    seq = TumSequence(job.sequence.pop("path"), **job.sequence)
    masks = np.load(job.masks) if job.masks else None
    height, width = seq.image_size[1], seq.image_size[0]
    start = time.perf_counter()
    slam = pyorbslam3.Slam(job.vocabulary, job.settings, pyorbslam3.Sensor.RGBD)
    loaded = time.perf_counter()
    stamps = seq.stamps
    states: list[str] = []
    carrier = None if job.thread is None else make_carrier(job.thread)
    blanked = 0
    carry_s = 0.0
    frames = seq.frames()
    try:
        for frame in frames:
            tick = time.perf_counter()
            mask = None
            if masks is not None:
                bits = np.unpackbits(masks[frame.index], count=width * height)
                mask = bits.reshape(height, width).astype(bool)
            if carrier is not None:
                carry = time.perf_counter()
                mask = carrier.region(frame)
                carry_s += time.perf_counter() - carry
                blanked += 0 if mask is None else int(mask.sum())
            filled = None if job.filled is None else read_filled(job.filled, frame.index)
            rgb, depth = blank_dynamic(frame.rgb, frame.depth, mask, job.blank_value, filled)
            if not job.rgb:
                rgb = np.ascontiguousarray(rgb[:, :, ::-1])
            if job.depth_factor != 1.0:
                depth = depth * np.float32(job.depth_factor)
            result = slam.track_rgbd(rgb, depth, frame.stamp)
            states.append(result.state.name)
            if carrier is not None:
                carry = time.perf_counter()
                carrier.tracked(frame, result.pose_wc if result.state.name == "OK" else None)
                carry_s += time.perf_counter() - carry
            if job.realtime:  # as ORB-SLAM3's rgbd_tum: wait until the next frame's time
                k = frame.index
                period = stamps[k + 1] - stamps[k] if k + 1 < len(stamps) else 0.0
                wait = period - (time.perf_counter() - tick)
                if wait > 0:
                    time.sleep(wait)
    finally:
        frames.close()
    tracked = time.perf_counter()
    slam.shutdown()
    if "OK" in states:  # ORB-SLAM3 saves relative to its first keyframe: none before init
        slam.save_trajectory_tum(job.trajectory)
    out: dict[str, Any] = {"states": states, "track_s": tracked - loaded, "load_s": loaded - start}
    if carrier is not None:
        n = max(len(states), 1)
        out["thread"] = {
            "delivered": carrier.delivered,
            "blanked_fraction": blanked / (n * width * height),
            "carry_ms": 1000 * carry_s / n,
        }
    Path(job.result).write_text(json.dumps(out), encoding="utf-8")


def make_carrier(spec: dict[str, Any]):
    """The :class:`~.thread.Carrier` of a job's ``thread`` entry."""
    from ...filters.build import build_filters
    from .thread import Carrier, Schedule, read_labels

    plan = Schedule(tuple(spec["segmented"]), tuple(spec["delivered"]), spec["latency_s"])
    masks = build_filters(spec["filters"], spec["filter_params"])
    return Carrier(plan, read_labels(spec["labels"]), np.asarray(spec["k"], np.float64), masks)


if __name__ == "__main__":  # the worker process of one repeat (see run_worker)
    work(sys.argv[1])

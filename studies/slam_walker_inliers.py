"""How much of a SLAM system's tracking rests on the walkers: per frame, the share of the pose's
inliers that lie on people, and the ATE, for harness settings and (optionally) the real ORB-SLAM3?
Reported in docs/results/slam.md, "2026-12-01/02 — why walkers fool ORB-SLAM3 more than the
harness's own policy", and BENCHMARKS.md, "ORB-SLAM3 next to the harness".

    python studies/slam_walker_inliers.py --sequence /tmp/walkers/wxyz7 \\
        --variant default --variant "kf_every_frame:tracker.max_keyframe_interval=1" \\
        --orbslam3 --vocabulary vocab.txt

The sequence is a synthetic one (``uss-synth sequence``) with ground-truth ``labels/``; nothing is
filtered (no segmenter), so each system sees the walkers as ORB-SLAM would.

- **Harness rows**: ``uss-slam``'s pipeline with the given overrides of ``slam.tracker.*``
  (``tracker.KEY=VALUE``), ``slam.local_ba`` (``local_ba=true``) and ``slam.local_ba_params.*``
  (``local_ba_params.KEY=VALUE``); ``default`` = no override. The tracker is wrapped to record
  each frame's final inliers (the keypoints matched to map points after the χ² tests), nothing
  in its behaviour changes. An inlier is *on people* when its keypoint's pixel is labelled
  person in the frame's ``labels/`` image; *from people* when its map point was created from a
  person keypoint (the point's first keyframe).
- **ORB-SLAM3 row** (``--orbslam3``, needs pyorbslam3 and ``--vocabulary``): one fresh process
  per repeat; ``tracked_map_points()`` of each frame (the map points of the frame's inliers
  after its pose optimisation) are projected with ORB-SLAM3's pose of that frame and are on
  people when they land on a person pixel (ORB-SLAM3's χ² test keeps them within ~3 px of
  their keypoint). "online ATE" is the ATE of the poses ``track_rgbd`` returned frame by frame,
  "ATE" that of the trajectory saved after shutdown (keyframes after local BA and loop closing).

Columns: ATE RMSE (mm), tracked frames, mean inliers per tracked frame, the share of inliers on
people (mean over tracked frames, 90th percentile, maximum, frames where it exceeds 25%) and the
share of inliers *from* people (harness only). ``--json`` also writes every frame's counts.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import yaml

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import Trajectory, read_trajectory
from uss_slam.slam_eval.mapping.local_mapping import LocalMappingConfig
from uss_slam.slam_eval.scoring.evaluation import EvalConfig, evaluate
from uss_slam.slam_eval.segmenters.base import NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems import harness
from uss_slam.slam_eval.tracking.tracker import Tracker, TrackerConfig

PERSON = CLASS_NAMES.index("person")
HIGH_SHARE = 0.25
"""A frame counts as dominated by walkers when more than this share of its inliers is on people."""


@dataclass
class Variant:
    """Harness settings of one row: a name and ``section.key=value`` overrides."""

    name: str
    tracker: dict[str, Any] = field(default_factory=dict)
    local_ba: bool = False
    local_ba_params: dict[str, Any] = field(default_factory=dict)


def _typed(cls: type, key: str, text: str, where: str) -> Any:
    """``text`` parsed as YAML and checked against the type of ``cls``'s field ``key``."""
    known = {f.name: f for f in fields(cls)}
    if key not in known:
        raise UssSlamError(f"{where}: unknown key {key!r}; expected one of {', '.join(known)}")
    value = yaml.safe_load(text)
    default = getattr(cls(), key)
    if isinstance(default, bool) != isinstance(value, bool) or (
        isinstance(default, (int, float)) and not isinstance(value, (int, float))
    ):
        raise UssSlamError(f"{where}: {key} expects a value like {default!r}, got {text!r}")
    return value


def parse_variant(spec: str) -> Variant:
    """``NAME`` or ``NAME:KEY=VALUE[,KEY=VALUE...]`` with keys ``tracker.<field>``,
    ``local_ba`` and ``local_ba_params.<field>`` (``default`` = no override)."""
    name, _, rest = spec.partition(":")
    if not name:
        raise UssSlamError(f"--variant {spec!r}: expected NAME[:KEY=VALUE,...]")
    variant = Variant(name)
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, text = item.partition("=")
        where = f"--variant {name}: {item!r}"
        if not eq:
            raise UssSlamError(f"{where}: expected KEY=VALUE")
        section, _, sub = key.partition(".")
        if section == "tracker" and sub:
            variant.tracker[sub] = _typed(TrackerConfig, sub, text, where)
        elif section == "local_ba_params" and sub:
            variant.local_ba_params[sub] = _typed(LocalMappingConfig, sub, text, where)
        elif key == "local_ba":
            value = yaml.safe_load(text)
            if not isinstance(value, bool):
                raise UssSlamError(f"{where}: local_ba expects true or false")
            variant.local_ba = value
        else:
            raise UssSlamError(
                f"{where}: keys are tracker.<field>, local_ba, local_ba_params.<field>"
            )
    try:
        TrackerConfig(**variant.tracker)
        LocalMappingConfig(**variant.local_ba_params)
    except ValueError as err:
        raise UssSlamError(f"--variant {name}: {err}") from None
    return variant


@dataclass
class FrameCount:
    """One frame: ``inliers`` of its final pose, how many are ``on`` people (keypoint pixel) and
    ``from`` people (map point created on a person); -1 where not measured."""

    index: int
    tracked: bool
    inliers: int
    on: int
    origin: int = -1


@dataclass
class RowResult:
    name: str
    ate_rmse: float | None
    frames: list[FrameCount]
    online_ate_rmse: float | None = None
    keyframes: int | None = None
    """Keyframes in the final map (ORB-SLAM3: after its keyframe culling)."""
    seconds: float = 0.0
    run: harness.RunResult | None = None
    """The harness's own result (trajectory, per-frame log); None for ORB-SLAM3."""


class _RecordingTracker(Tracker):
    """The harness's tracker, unchanged, remembering each frame's inliers and the keypoints that
    created map points (read after the run; nothing here feeds back into tracking)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.record: list[tuple[int, bool, np.ndarray, np.ndarray]] = []
        """``(frame index, tracked, inlier keypoint uv (M, 2), their map point ids (M,))``."""
        self.created: list[tuple[int, np.ndarray, np.ndarray]] = []
        """``(frame index, uv (K, 2), new map point ids (K,))`` per keyframe."""

    def track(self, frame_index, stamp, features, dynamic):  # type: ignore[no-untyped-def]
        result = super().track(frame_index, stamp, features, dynamic)
        if result.new_keyframe is not None:  # the first keyframe: every point is new
            self._created(frame_index, features, result.new_keyframe.point_ids, None)
        return result

    def finish_frame(self, frame_index, stamp, result, features, dynamic, keyframe=None):  # type: ignore[no-untyped-def]
        first = result.new_keyframe is not None  # inserted by track(): its points are new
        inliers = result.matched.copy()
        kf = super().finish_frame(frame_index, stamp, result, features, dynamic, keyframe)
        if kf is not None and not first:
            self._created(frame_index, features, kf.point_ids, inliers)
        good = np.flatnonzero(inliers >= 0)
        self.record.append(
            (frame_index, result.pose_wc is not None, features.uv[good], inliers[good])
        )
        return kf

    def _created(self, frame_index, features, point_ids, before) -> None:  # type: ignore[no-untyped-def]
        new = point_ids >= 0 if before is None else (point_ids >= 0) & (before < 0)
        idx = np.flatnonzero(new)
        self.created.append((frame_index, features.uv[idx], point_ids[idx]))


def _labels(sequence: TumSequence) -> dict[int, np.ndarray]:
    out = {}
    for frame in sequence.frames():
        if frame.labels is None:
            raise UssSlamError(f"{sequence.path}: no labels/ image for frame {frame.index}")
        out[frame.index] = frame.labels == PERSON
    return out


def _on_people(mask: np.ndarray, uv: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    u = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    return inside & mask[v, u]


def run_harness(path: Path, variant: Variant, people: dict[int, np.ndarray]) -> RowResult:
    """One harness run with the variant's settings; per-frame inliers on / from people."""
    seq = TumSequence(path, load_labels=False)
    made: list[_RecordingTracker] = []

    def factory(*args: Any, **kwargs: Any) -> _RecordingTracker:
        made.append(_RecordingTracker(*args, **kwargs))
        return made[-1]

    run = harness.SlamPipeline(
        seq,
        NoSegmenter(),
        [],
        tracker=replace(TrackerConfig(), **variant.tracker),
        local_ba=variant.local_ba,
        local_ba_params=replace(LocalMappingConfig(), **variant.local_ba_params),
        progress=False,
    )
    start = time.perf_counter()
    with mock.patch.object(harness, "Tracker", factory):
        result = run.run()
    seconds = time.perf_counter() - start
    tracker = made[0]
    from_people: set[int] = set()
    for index, uv, ids in tracker.created:
        from_people.update(ids[_on_people(people[index], uv)].tolist())
    origin = np.zeros(tracker.map.n_points, bool)
    origin[list(from_people)] = True
    frames = [
        FrameCount(
            index,
            tracked,
            len(ids),
            int(_on_people(people[index], uv).sum()),
            int(origin[ids].sum()),
        )
        for index, tracked, uv, ids in tracker.record
    ]
    ev = evaluate(result.trajectory, seq.groundtruth, EvalConfig())
    ate = None if ev.ate is None else ev.ate.stats.rmse
    return RowResult(
        variant.name, ate, frames, keyframes=result.keyframes, seconds=seconds, run=result
    )


# ----------------------------------------------------------------------------------- ORB-SLAM3


def _orbslam3_worker(job_path: str) -> None:
    """One ORB-SLAM3 run (fresh process): per frame its pose and the projected map points on
    people; its trajectory after shutdown."""
    import pyorbslam3

    from uss_slam.slam_eval.systems.orbslam3.config import OrbSlam3Config
    from uss_slam.slam_eval.systems.orbslam3.settings import frame_rate, settings_yaml

    job = json.loads(Path(job_path).read_text())
    out = Path(job["out"])
    seq = TumSequence(job["sequence"], load_labels=True)
    config = OrbSlam3Config(vocabulary=job["vocabulary"])
    settings = out / "settings.yaml"
    settings.write_text(settings_yaml(seq.camera, config, frame_rate(seq.stamps)))
    slam = pyorbslam3.Slam(config.vocabulary, str(settings), pyorbslam3.Sensor.RGBD)
    k = seq.camera.matrix
    rows = []
    frames = seq.frames()
    try:
        for frame in frames:
            tick = time.perf_counter()
            result = slam.track_rgbd(frame.rgb, frame.depth, frame.stamp)
            ok = result.state.name == "OK" and result.pose_cw is not None
            row: dict[str, Any] = {"index": frame.index, "stamp": frame.stamp, "ok": ok}
            if ok:
                pose_cw = np.asarray(result.pose_cw, np.float64)
                world = np.asarray(slam.tracked_map_points(), np.float64).reshape(-1, 3)
                cam = world @ pose_cw[:3, :3].T + pose_cw[:3, 3]
                front = cam[:, 2] > 1e-6
                uv = (cam[front] / cam[front, 2:3]) @ k.T
                row["inliers"] = len(world)
                row["on"] = int(_on_people(frame.labels == PERSON, uv[:, :2]).sum())
                row["pose_wc"] = np.linalg.inv(pose_cw).tolist()
            rows.append(row)
            wait = job["period"] - (time.perf_counter() - tick)
            if wait > 0:  # as ORB-SLAM3's rgbd_tum example: no faster than the camera
                time.sleep(wait)
    finally:
        frames.close()
    slam.shutdown()
    slam.save_trajectory_tum(str(out / "trajectory.txt"))
    slam.save_keyframe_trajectory_tum(str(out / "keyframes.txt"))
    (out / "frames.json").write_text(json.dumps(rows))


def run_orbslam3(path: Path, vocabulary: Path, workdir: Path, repeat: int) -> RowResult:
    out = workdir / f"orbslam3_{repeat}"
    out.mkdir(parents=True, exist_ok=True)
    seq = TumSequence(path)
    period = float(np.median(np.diff(seq.stamps))) if len(seq.stamps) > 1 else 0.0
    job = out / "job.json"
    job.write_text(
        json.dumps(
            {
                "sequence": str(path),
                "vocabulary": str(vocabulary),
                "out": str(out),
                "period": period,
            }
        )
    )
    start = time.perf_counter()
    with open(out / "orbslam3.log", "wb") as log:
        proc = subprocess.run(
            [sys.executable, __file__, "--orbslam3-worker", str(job)],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            check=False,
        )
    seconds = time.perf_counter() - start
    if proc.returncode != 0 or not (out / "frames.json").is_file():
        raise UssSlamError(
            f"ORB-SLAM3 repeat {repeat} failed (exit {proc.returncode}): see {log.name}"
        )
    rows = json.loads((out / "frames.json").read_text())
    frames = [FrameCount(r["index"], r["ok"], r.get("inliers", 0), r.get("on", 0)) for r in rows]
    tracked = [r for r in rows if r["ok"]]
    online = None
    if len(tracked) >= 3:
        traj = Trajectory.from_matrices(
            [r["stamp"] for r in tracked], np.array([r["pose_wc"] for r in tracked])
        )
        ev = evaluate(traj, seq.groundtruth, EvalConfig())
        online = None if ev.ate is None else ev.ate.stats.rmse
    ate = None
    if (out / "trajectory.txt").is_file():
        ev = evaluate(read_trajectory(out / "trajectory.txt"), seq.groundtruth, EvalConfig())
        ate = None if ev.ate is None else ev.ate.stats.rmse
    keyframes = None
    if (out / "keyframes.txt").is_file():
        keyframes = len(read_trajectory(out / "keyframes.txt"))
    return RowResult(f"ORB-SLAM3 #{repeat}", ate, frames, online, keyframes, seconds)


# ----------------------------------------------------------------------------------- table


def summary(row: RowResult) -> dict[str, Any]:
    tracked = [f for f in row.frames if f.tracked and f.inliers > 0]
    share = np.array([f.on / f.inliers for f in tracked]) if tracked else np.zeros(0)
    origin = [f.origin / f.inliers for f in tracked if f.origin >= 0]
    return {
        "name": row.name,
        "ate_mm": None if row.ate_rmse is None else 1000 * row.ate_rmse,
        "online_ate_mm": None if row.online_ate_rmse is None else 1000 * row.online_ate_rmse,
        "tracked": sum(f.tracked for f in row.frames),
        "keyframes": row.keyframes,
        "frames": len(row.frames),
        "mean_inliers": float(np.mean([f.inliers for f in tracked])) if tracked else 0.0,
        "on_mean": float(share.mean()) if len(share) else 0.0,
        "on_p90": float(np.percentile(share, 90)) if len(share) else 0.0,
        "on_max": float(share.max()) if len(share) else 0.0,
        "frames_over": int((share > HIGH_SHARE).sum()),
        "from_mean": float(np.mean(origin)) if origin else None,
        "seconds": row.seconds,
    }


def _mm(value: float | None) -> str:
    return "—" if value is None else f"{value:.1f}"


def table(rows: list[dict[str, Any]]) -> str:
    head = (
        "| run | ATE RMSE [mm] | online ATE [mm] | tracked | keyframes | inliers / frame "
        "| on people: mean "
        f"| p90 | max | frames > {HIGH_SHARE:.0%} | from people: mean |"
    )
    lines = [head, "|" + "---|" * 11]
    for s in rows:
        origin = "—" if s["from_mean"] is None else f"{100 * s['from_mean']:.1f}%"
        lines.append(
            f"| {s['name']} | {_mm(s['ate_mm'])} | {_mm(s['online_ate_mm'])} "
            f"| {s['tracked']}/{s['frames']} | {'—' if s['keyframes'] is None else s['keyframes']} "
            f"| {s['mean_inliers']:.0f} "
            f"| {100 * s['on_mean']:.1f}% | {100 * s['on_p90']:.1f}% | {100 * s['on_max']:.1f}% "
            f"| {s['frames_over']} | {origin} |"
        )
    return "\n".join(lines)


def _progress(row: RowResult) -> None:
    """One line per finished run on stderr (a long comparison shows its rows as they come)."""
    s = summary(row)
    print(
        f"{row.name}: ATE {_mm(s['ate_mm'])} mm, on people {100 * s['on_mean']:.1f}% "
        f"({row.seconds:.0f} s)",
        file=sys.stderr,
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sequence", type=Path, help="synthetic TUM folder with labels/")
    parser.add_argument(
        "--variant",
        action="append",
        default=None,
        help="NAME or NAME:KEY=VALUE,... (keys tracker.<field>, local_ba, local_ba_params.<field>);"
        " repeatable (default: default)",
    )
    parser.add_argument("--orbslam3", action="store_true", help="also run ORB-SLAM3 (pyorbslam3)")
    parser.add_argument("--no-harness", action="store_true", help="ORB-SLAM3 rows only")
    parser.add_argument("--vocabulary", type=Path, help="DBoW2 text vocabulary for --orbslam3")
    parser.add_argument("--repeats", type=int, default=1, help="ORB-SLAM3 runs (default: 1)")
    parser.add_argument("--json", type=Path, help="also write summaries and per-frame counts")
    parser.add_argument("--orbslam3-worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.orbslam3_worker:
        _orbslam3_worker(args.orbslam3_worker)
        return 0
    try:
        if args.sequence is None:
            raise UssSlamError("--sequence: required")
        if args.orbslam3 and (args.vocabulary is None or not args.vocabulary.is_file()):
            raise UssSlamError("--orbslam3 needs --vocabulary FILE (uss-vocab build)")
        variants = [parse_variant(s) for s in args.variant or ["default"]]
        labelled = TumSequence(args.sequence, load_labels=True)
        people = _labels(labelled)
        results = []
        for variant in [] if args.no_harness else variants:
            results.append(run_harness(args.sequence, variant, people))
            _progress(results[-1])
        if args.orbslam3:
            with tempfile.TemporaryDirectory(prefix="walker_inliers_") as tmp:
                for repeat in range(args.repeats):
                    results.append(run_orbslam3(args.sequence, args.vocabulary, Path(tmp), repeat))
                    _progress(results[-1])
    except UssSlamError as err:
        print(f"slam_walker_inliers: error: {err}", file=sys.stderr)
        return 1
    rows = [summary(r) for r in results]
    print(f"`{args.sequence}`, {len(people)} frames, no filter\n")
    print(table(rows))
    if args.json:
        frames = {r.name: [vars(f) for f in r.frames] for r in results}
        args.json.write_text(json.dumps({"rows": rows, "frames": frames}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

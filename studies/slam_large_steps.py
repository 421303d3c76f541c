"""Why does a repeat go wrong at a large frame step? Runs ``uss-slam`` (its own arguments, e.g.
``slam.repeats=5 sequence.stride=3``) with the tracker instrumented, and prints per repeat its
ATE and the frames whose tracked step (the pose the tracker accepted, online, before any back
end moved it, against the previous tracked frame) is furthest from the ground truth's: the
frame, the ground truth's rotation over that step, the step's rotation / translation error,
the route that accepted it (``motion``: constant-velocity model + local map; ``reference``: the
reference keyframe + local map; ``reloc``: relocalisation), its map-point inliers after the
motion model's optimisation and after the local map, and whether it became a keyframe.

    python studies/slam_large_steps.py sequence.path=DIR sequence.camera=fr1 sequence.stride=3 \\
        slam.repeats=5 out_dir=/tmp/run [--top 3] [--json steps.json]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from uss_slam.core.tum_io import read_trajectory
from uss_slam.slam_eval import run
from uss_slam.slam_eval.tracking import tracker as tr

RUNS: list[list[dict]] = []
"""Per repeat (a new :class:`Tracker` each), per tracked frame: what accepted it."""

_track = tr.Tracker.track
_motion = tr.Tracker._track_last_frame
_reference = tr.Tracker._track_reference
_finish = tr.Tracker.finish_frame


def _init(self, *args, **kwargs):
    _tracker_init(self, *args, **kwargs)
    RUNS.append([])
    self._trace = {}


_tracker_init = tr.Tracker.__init__


def track(self, frame_index, stamp, features, dynamic):
    self._trace = {"frame": frame_index, "stamp": stamp, "route": []}
    res = _track(self, frame_index, stamp, features, dynamic)
    self._trace.update(inliers=res.inliers, relocalised=res.relocalised)
    self._trace["pose_wc"] = None if res.pose_wc is None else res.pose_wc.tolist()
    RUNS[-1].append(self._trace)
    return res


def motion(self, features, static):
    self._trace["route"].append("motion")
    return _motion(self, features, static)


def reference(self, features, static):
    self._trace["route"].append("reference")
    return _reference(self, features, static)


def finish(self, frame_index, stamp, result, features, dynamic, keyframe=None):
    kf = _finish(self, frame_index, stamp, result, features, dynamic, keyframe)
    if RUNS and RUNS[-1] and RUNS[-1][-1]["frame"] == frame_index:
        RUNS[-1][-1]["keyframe"] = kf is not None or result.new_keyframe is not None
        RUNS[-1][-1]["pose_wc"] = None if result.pose_wc is None else result.pose_wc.tolist()
    return kf


def angle(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def nearest(gt, stamp: float) -> np.ndarray:
    """The ground-truth pose (4, 4) nearest ``stamp`` (TUM's motion capture: 100 Hz)."""
    stamps, mats = gt
    return mats[int(np.abs(stamps - stamp).argmin())]


def steps(frames: list[dict], gt) -> list[dict]:
    """Per tracked frame after the first: its step against the previous tracked frame."""
    out = []
    prev = None
    for f in frames:
        if f["pose_wc"] is None:
            prev = None
            continue
        if prev is not None:
            g0, g1 = (nearest(gt, s) for s in (prev["stamp"], f["stamp"]))
            e0, e1 = np.array(prev["pose_wc"]), np.array(f["pose_wc"])
            rel_g, rel_e = np.linalg.inv(g0) @ g1, np.linalg.inv(e0) @ e1
            err = np.linalg.inv(rel_g) @ rel_e
            out.append(
                {
                    "frame": f["frame"],
                    "gt_rotation_deg": angle(rel_g[:3, :3]),
                    "error_deg": angle(err[:3, :3]),
                    "error_cm": 100 * float(np.linalg.norm(err[:3, 3])),
                    "route": "reloc" if f["relocalised"] else "+".join(f["route"]) or "?",
                    "inliers": f["inliers"],
                    "keyframe": bool(f.get("keyframe")),
                }
            )
        prev = f
    return out


def main() -> None:
    args = sys.argv[1:]
    top, dump = 3, None
    if "--top" in args:
        k = args.index("--top")
        top = int(args[k + 1])
        del args[k : k + 2]
    if "--json" in args:
        k = args.index("--json")
        dump = Path(args[k + 1])
        del args[k : k + 2]
    tr.Tracker.__init__ = _init
    tr.Tracker.track = track
    tr.Tracker._track_last_frame = motion
    tr.Tracker._track_reference = reference
    tr.Tracker.finish_frame = finish
    out = next(a.split("=", 1)[1] for a in args if a.startswith("out_dir="))
    seq = next(a.split("=", 1)[1] for a in args if a.startswith("sequence.path="))
    sys.argv = ["uss-slam", *args, "progress=false"]
    try:
        run.main()
    except SystemExit as end:
        if end.code not in (0, None):
            raise
    metrics = json.loads((Path(out) / "metrics.json").read_text())
    repeats = metrics.get("repeats") or [{"ate_rmse": metrics["ate"]["rmse"]}]
    traj = read_trajectory(Path(seq) / "groundtruth.txt")
    gt = (traj.stamps, traj.matrices())
    report = []
    for i, (frames, rep) in enumerate(zip(RUNS, repeats, strict=True)):
        st = steps(frames, gt)
        worst = sorted(st, key=lambda s: -s["error_deg"])[:top]
        report.append({"repeat": i, "ate_rmse": rep["ate_rmse"], "steps": st})
        text = "; ".join(
            f"frame {s['frame']}: truth {s['gt_rotation_deg']:.1f}°, off {s['error_deg']:.2f}° "
            f"{s['error_cm']:.1f} cm, {s['route']} {s['inliers']} inl"
            + (" KF" if s["keyframe"] else "")
            for s in worst
        )
        print(f"repeat {i} ATE {rep['ate_rmse']:.4f}: {text}")
    if dump is not None:
        dump.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()

"""Trace the tracker's per-frame decisions (motion-model matches per window, the inliers of the
local-map step, fallbacks to the reference keyframe, relocalisations) of a ``uss-slam`` run:
the console script's arguments, one line per decision on stderr.

    python studies/slam_track_trace.py sequence.path=... sequence.stride=3 slam.repeats=5 ...
"""

from __future__ import annotations

import sys

from uss_slam.slam_eval import run
from uss_slam.slam_eval.matching.projection import ProjectionMatcher
from uss_slam.slam_eval.tracking import tracker as tr


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


_match_points = ProjectionMatcher.match_points
_ref = tr.Tracker._track_reference
_vo = tr.Tracker._track_local_map_vo
_reloc = tr.relocalise
_track = tr.Tracker.track


def match_points(self, world, desc, level, pose_cw, features, available, radius, angle=None):
    q, kp = _match_points(self, world, desc, level, pose_cw, features, available, radius, angle)
    log(f"    motion r={radius:g}: {len(q)} of {len(world)} matched")
    return q, kp


def ref(self, features, static):
    out = _ref(self, features, static)
    n = -1 if out[1] is None else int((out[1] >= 0).sum())
    log(f"    reference keyframe: {n} inliers")
    return out


def vo(self, pose_cw, features, static, world, map_ids, kp):
    out = _vo(self, pose_cw, features, static, world, map_ids, kp)
    n = -1 if out[1] is None else int((out[1] >= 0).sum())
    log(f"    motion: {len(kp)} inliers ({int((map_ids >= 0).sum())} map), local map -> {n}")
    return out


def track(self, frame_index, stamp, features, dynamic):
    log(f"frame {frame_index} ({len(features)} kp)")
    res = _track(self, frame_index, stamp, features, dynamic)
    log(f"  -> {res.state.value} inliers {res.inliers} reloc {res.relocalised}")
    return res


ProjectionMatcher.match_points = match_points
tr.Tracker._track_reference = ref
tr.Tracker._track_local_map_vo = vo
tr.Tracker.track = track

if __name__ == "__main__":
    sys.argv = ["uss-slam", *sys.argv[1:]]
    run.main()

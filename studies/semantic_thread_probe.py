"""Where do the people still get in with the semantic thread? One ``uss-slam`` run (its config,
``slam.repeats=1``) on a synthetic sequence with ground-truth ``labels/``, counting per frame,
against the frame's own ground truth (the semantic filter's dynamic classes, undilated):

- ``person_inliers``: the frame's pose inliers whose keypoint lies on a person (what steers the
  pose wrong), and ``inliers`` in all;
- per new keyframe, ``created`` map points and ``created_on_person`` (people mapped), and
  why the tracker asked for it (``reason``: ``ratio``, fewer inliers than ``keyframe_ratio`` of
  the reference keyframe's tracked points ``ref_tracked``; ``close``, too few close points
  tracked (``tracked_close``) while many are not (``untracked_close``, of which
  ``untracked_close_on_person`` on a person); ORB-SLAM2's rule, :func:`~uss_slam.slam_eval.tracking.keyframes.need_keyframe`).

Recorded in docs/results/slam.md ("each delivered mask carried to the keyframes that got none").

    python studies/semantic_thread_probe.py SEQ --out OUT.json --set segment=thread \\
        segmenter.latency_s=0.5 [KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir

from uss_slam.slam_eval.config import register_configs
from uss_slam.slam_eval.filters.base import values_at
from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.systems.frame_loop import FrameLoop
from uss_slam.slam_eval.tracking import tracker as tracker_module

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


def decisions(record: dict) -> None:
    """Wrap the tracker's keyframe rule so that each call leaves its inputs in ``record``
    (the last call's: ``inliers``, ``ref_tracked``, ``reason``)."""
    rule = tracker_module.need_keyframe

    def wrapped(cfg, slam_map, reference, index, reloc, since, features, matched, dynamic):
        answer = rule(cfg, slam_map, reference, index, reloc, since, features, matched, dynamic)
        ids = reference.point_ids[reference.point_ids >= 0]
        ids = ids[~slam_map.points.bad.view[ids]]
        min_obs = 2 if len(slam_map.keyframes) > 2 else 1
        ref = int((slam_map.points.observations.view[ids] >= min_obs).sum())
        inliers = int((matched >= 0).sum())
        ratio = inliers < cfg.keyframe_ratio * ref
        close = (features.depth > 0) & (features.depth < cfg.th_depth) & ~dynamic
        record.clear()
        record.update(
            index=index, ref_tracked=ref, answer=answer, reason="ratio" if ratio else "close",
            tracked_close=int((close & (matched >= 0)).sum()),
            untracked_close=features.xy[close & (matched < 0)],
        )  # fmt: skip
        return answer

    tracker_module.need_keyframe = wrapped


def probe(loop: FrameLoop, frame, filters, result, kf, rows: list[dict], last: dict) -> None:
    """Append the frame's counts (module docstring) to ``rows``."""
    semantic = [f for f in loop.chain.filters if isinstance(f, SemanticFilter)]
    if frame.labels is None or not semantic:
        return
    person = np.isin(frame.labels, semantic[0].ids)
    xy = filters.ctx.features.xy
    on = values_at(person, xy) if len(xy) else np.zeros(0, bool)
    matched = result.matched if result.matched is not None else np.full(len(xy), -1)
    row = {
        "index": frame.index,
        "tracked": result.pose_wc is not None,
        "inliers": int((matched >= 0).sum()),
        "person_inliers": int(((matched >= 0) & on).sum()),
        "keyframe": kf is not None,
    }
    if kf is not None:
        ids = kf.point_ids
        own = (ids >= 0) & (loop.map.points.first_keyframe.view[np.maximum(ids, 0)] == kf.id)
        kf_on = values_at(person, kf.features.xy)
        row["created"] = int(own.sum())
        row["created_on_person"] = int((own & kf_on).sum())
        if last.get("index") == frame.index and last["answer"]:
            untracked = last["untracked_close"]
            row.update(
                reason=last["reason"], ref_tracked=last["ref_tracked"],
                tracked_close=last["tracked_close"], untracked_close=len(untracked),
                untracked_close_on_person=int(values_at(person, untracked).sum())
                if len(untracked) else 0,
            )  # fmt: skip
    rows.append(row)


def summary(rows: list[dict], metrics: dict) -> dict:
    """The run's ATE, keyframes and the counts' totals and means."""
    kfs = [r for r in rows if r["keyframe"]]
    person = [r["person_inliers"] for r in rows]
    return {
        "ate_rmse": metrics["ate"]["rmse"],
        "keyframes": len(kfs),
        "mean_inliers": statistics.fmean(r["inliers"] for r in rows),
        "mean_person_inliers": statistics.fmean(person),
        "frames_with_10_person_inliers": sum(p >= 10 for p in person),
        "created": sum(r.get("created", 0) for r in kfs),
        "created_on_person": sum(r.get("created_on_person", 0) for r in kfs),
        "reasons": {k: sum(r.get("reason") == k for r in kfs) for k in ("ratio", "close")},
        "untracked_close": sum(r.get("untracked_close", 0) for r in kfs),
        "untracked_close_on_person": sum(r.get("untracked_close_on_person", 0) for r in kfs),
        "semantic_thread": (metrics.get("segmentation") or {}).get("semantic_thread"),
    }


def run_once(sequence: Path, overrides: list[str]) -> dict:
    """One ``uss-slam`` run of ``sequence`` (the probe's fixed keys, then ``overrides``) in a
    temporary folder; its ``metrics.json``."""
    register_configs()
    with (
        tempfile.TemporaryDirectory() as tmp,
        initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"),
    ):
        cfg = compose("slam_eval", overrides=[
            f"sequence.path={sequence}", f"out_dir={tmp}", "progress=false",
            "segmenter=labels", "filters=[semantic]", "slam.repeats=1", *overrides,
        ])  # fmt: skip
        run(cfg)
        return json.loads((Path(tmp) / "metrics.json").read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", dest="overrides")
    args = parser.parse_args()
    rows: list[dict] = []
    last: dict = {}
    rule, record = tracker_module.need_keyframe, FrameLoop.record
    decisions(last)

    def recording(self, frame, filters, result, kf):
        probe(self, frame, filters, result, kf, rows, last)
        record(self, frame, filters, result, kf)

    FrameLoop.record = recording
    try:
        metrics = run_once(args.sequence, args.overrides)
    finally:
        tracker_module.need_keyframe, FrameLoop.record = rule, record
    out = {"overrides": args.overrides, **summary(rows, metrics), "frames": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1))
    print(json.dumps({k: v for k, v in out.items() if k != "frames"}))


if __name__ == "__main__":
    main()

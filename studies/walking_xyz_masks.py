"""Where does the error come from when a trained segmenter's person masks make the harness worse
than no filter? Per frame of one ``uss-slam`` run per model: the walkers' keypoints the semantic
filter removes and keeps, the static keypoints it removes, the walkers' share among the pose's
inliers and among the new map points, how the mask's cover of the walkers changes from frame to
frame, and the drift of each one-second window. Reported in
docs/results/warm_start_main/walking_xyz_why.md.

    python studies/walking_xyz_masks.py --sequence OUT/data/eval/walking_xyz \\
        --sequence OUT/data/eval/walking_rpy --model none --model labels \\
        --model source_only_s0=OUT/exports/source_only_s0/source_only_s0.onnx [...] \\
        [--split [walkers,static,moved]] [--max-frames N] [--window 30] [--json F]

Each ``--model`` is ``none`` (no filter), ``labels`` (the sequence's ground-truth masks) or
``NAME=PATH`` (an exported ONNX segmenter). Every run is ``uss-slam`` as ``uss-experiments``
composes its jobs (``segmenter=onnx segmenter.path=PATH filters=[semantic]``, every other
setting at its default: ORB-SLAM2's tracking policy, local BA and loop closing on), with one
repeat: the deterministic run (repeat 0 of a job's ``repeats/``). The harness's tracker is
wrapped as in ``studies/slam_walker_inliers.py`` (its recording tracker): nothing in its
behaviour changes. A keypoint is a *walker* keypoint when its pixel is labelled person in the
frame's ``labels/`` image (undilated); the filter removes the keypoints inside the predicted
person mask dilated by 5 px. ``--split`` adds, for each ONNX model, runs with part of its
person mask: ``NAME:walkers`` keeps only its pixels on the walkers (its hits), ``NAME:static``
only its pixels off them (its false alarms; the 5 px dilation may still reach a walker's edge):
which part of the mask changes the run; ``NAME:moved`` replaces the mask by as many walker
pixels as it hits, on the other side of the walkers: whether these walker keypoints matter or
any as many. Printed per sequence:
- the render: frames with walkers, the walkers' mean share of the frame, the median depth of
  their pixels, their share of the ORB keypoints (in the ``none`` run, when there is one);
- per model, the filter: ATE RMSE, walker keypoints per frame and the share removed, static
  keypoints removed per frame (and their share), the walkers' share among the kept keypoints;
  the mask's per-frame pixel recall on the walkers; *cover* per frame = share of that frame's
  walker keypoints removed (frames with at least 10): frames with cover < 10% ("missed") and
  >= 50%, and the mean change of cover from one such frame to the next (flicker);
- per model, tracking: inliers per frame, the walkers' share among them (pooled, frames over
  25%), the share of inliers whose map point was created on a walker, the walkers' share of
  the new map points, and the share of those walker map points created in missed frames;
- per one-second window (``--window`` frames), the translational RPE over the window (mm) and
  the walkers' share of the inliers in it, for every model; and, pooled over the models and
  windows of the sequence, the Spearman rank correlation of the two.

It measures; nothing here chooses a setting (on evaluation renders nothing may be chosen).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import read_trajectory
from uss_slam.pipelines.runs import Segmenter, SlamJob, run_slam
from uss_slam.slam_eval.scoring.metrics import rpe
from uss_slam.slam_eval.segmenters.base import ImageSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems import harness
from uss_slam.testing.scripts import load_script

walker_inliers = load_script(Path(__file__).resolve().parent / "slam_walker_inliers.py")
on_people = walker_inliers._on_people

PERSON = CLASS_NAMES.index("person")
MIN_WALKER_KP = 10
"""A frame's cover is measured when it has at least this many walker keypoints."""
MISSED = 0.10
"""A frame whose mask removes less than this share of its walker keypoints is *missed*."""
COVERED = 0.50
HIGH_SHARE = walker_inliers.HIGH_SHARE


@dataclass
class Render:
    """The ground truth of one sequence: per frame the person mask, its share of the frame and
    the median depth of its pixels (metres; NaN without person pixels or depth)."""

    path: Path
    people: dict[int, np.ndarray]
    area: dict[int, float]
    depth: dict[int, float]


PARTS = ("walkers", "static", "moved")
"""What ``--split`` runs of a model's person mask: its pixels on the walkers (its hits), its
pixels off them (its false alarms), and ``moved``: as many walker pixels as it hits, taken
elsewhere on the walkers (:func:`moved_hits`)."""


@dataclass
class ModelSpec:
    """A run's segmenter and filters; ``part``: only that part of the model's person mask
    (:data:`PARTS`; None = all of it)."""

    name: str
    segmenter: Segmenter
    filters: tuple[str, ...]
    part: str | None = None


def split(model: ModelSpec, parts: tuple[str, ...] = PARTS) -> list[ModelSpec]:
    """``model`` and, for an ONNX model, its mask's ``parts`` (``NAME:walkers``, ...)."""
    if model.segmenter.kind != "onnx":
        return [model]
    return [model] + [
        ModelSpec(f"{model.name}:{part}", model.segmenter, model.filters, part) for part in parts
    ]


def parse_parts(text: str) -> tuple[str, ...]:
    """``--split``'s comma-separated parts, each one of :data:`PARTS`."""
    parts = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in parts if p not in PARTS]
    if not parts or bad:
        raise UssSlamError(
            f"--split {text!r}: expected a comma-separated list of {', '.join(PARTS)}"
        )
    return parts


def moved_hits(hits: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """A control for a mask's hits on the walkers: as many walker pixels (``truth``) as ``hits``
    holds, the ones nearest to the hits' centroid reflected through the walkers' centroid, so
    the same amount of walker, in one piece, on the other side of the walkers (deterministic,
    and as steady from frame to frame as the hits). ``(H, W)`` bool in and out."""
    k = int(hits.sum())
    ys, xs = np.nonzero(truth)
    if k == 0 or k >= len(ys):
        return hits.copy() if k == 0 else truth.copy()
    hy, hx = np.nonzero(hits)
    ay, ax = 2 * ys.mean() - hy.mean(), 2 * xs.mean() - hx.mean()
    nearest = np.argpartition((ys - ay) ** 2 + (xs - ax) ** 2, k - 1)[:k]
    out = np.zeros_like(truth)
    out[ys[nearest], xs[nearest]] = True
    return out


@dataclass
class FrameRecord:
    """One frame of a run: keypoints (all, on walkers, removed on walkers, removed elsewhere),
    the pose's inliers (all, on walkers, from map points created on walkers), the map points it
    created (all, on walkers) and, for a model, the mask's person pixels on the walkers."""

    index: int
    tracked: bool
    keypoints: int
    walker: int
    walker_removed: int
    static_removed: int
    inliers: int
    on: int
    origin: int
    created: int = 0
    created_on: int = 0
    gt_pixels: int = 0
    hit_pixels: int = -1
    """-1: no segmenter ran (``none``)."""


@dataclass
class RunRecord:
    sequence: str
    model: str
    ate_mm: float | None
    frames: list[FrameRecord]
    window_rpe_mm: list[tuple[int, float]] = field(default_factory=list)
    """``(first frame index, translational RPE over the window in mm)`` per window."""


def parse_model(spec: str) -> ModelSpec:
    """``none``, ``labels`` or ``NAME=PATH`` (an ONNX export)."""
    if spec == "none":
        return ModelSpec("none", Segmenter("none"), ())
    if spec == "labels":
        return ModelSpec("labels", Segmenter("labels"), ("semantic",))
    name, eq, path = spec.partition("=")
    if not eq or not name or not path:
        raise UssSlamError(f"--model {spec!r}: expected none, labels or NAME=PATH.onnx")
    file = Path(path)
    if not file.is_file():
        raise UssSlamError(f"--model {name}: {file}: no such file (expected an ONNX export)")
    return ModelSpec(name, Segmenter.onnx(file), ("semantic",))


def read_render(path: Path, max_frames: int | None = None) -> Render:
    """The ground truth of the labelled sequence at ``path``."""
    if not (path / "labels").is_dir():
        raise UssSlamError(f"--sequence {path}: no labels/ folder (expected a synthetic sequence)")
    seq = TumSequence(path, load_labels=True, max_frames=max_frames)
    people, area, depth = {}, {}, {}
    frames = seq.frames()
    try:
        for frame in frames:
            if frame.labels is None:
                raise UssSlamError(f"{path}: no labels/ image for frame {frame.index}")
            mask = frame.labels == PERSON
            people[frame.index] = mask
            area[frame.index] = float(mask.mean())
            d = frame.depth[mask & (frame.depth > 0)]
            depth[frame.index] = float(np.median(d)) if d.size else float("nan")
    finally:
        frames.close()
    return Render(path, people, area, depth)


class _Recorder(walker_inliers._RecordingTracker):
    """slam_walker_inliers' recording tracker, also keeping each frame's keypoints and the
    filter's flags on them (read after the run; nothing feeds back into tracking)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.flags: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def finish_frame(self, frame_index, stamp, result, features, dynamic, keyframe=None):  # type: ignore[no-untyped-def]
        self.flags[frame_index] = (features.uv.copy(), np.asarray(dynamic, bool).copy())
        return super().finish_frame(frame_index, stamp, result, features, dynamic, keyframe)


def run_model(
    render: Render,
    model: ModelSpec,
    workdir: Path,
    window: int,
    max_frames: int | None = None,
) -> RunRecord:
    """One ``uss-slam`` run of ``model`` on ``render``'s sequence, recorded frame by frame."""
    made: list[_Recorder] = []
    pixels: dict[int, tuple[int, int]] = {}
    segment = ImageSegmenter.segment

    def factory(*args: Any, **kwargs: Any) -> _Recorder:
        made.append(_Recorder(*args, **kwargs))
        return made[-1]

    def counting(self: ImageSegmenter, frame: Any) -> np.ndarray:
        labels = segment(self, frame)
        truth = render.people[frame.index]
        if model.part is not None:  # the rest of the person mask becomes background
            labels = labels.copy()
            person = labels == PERSON
            if model.part == "moved":
                labels[person] = 0
                labels[moved_hits(person & truth, truth)] = PERSON
            else:
                labels[person & (truth if model.part == "static" else ~truth)] = 0
        pixels[frame.index] = (int(truth.sum()), int(((labels == PERSON) & truth).sum()))
        return labels

    out = workdir / f"{render.path.name}_{model.name}"
    job = SlamJob(
        render.path, model.segmenter, model.filters, ("slam.repeats=1",), None, max_frames
    )
    with (
        mock.patch.object(harness, "Tracker", factory),
        mock.patch.object(ImageSegmenter, "segment", counting),
    ):
        data = run_slam(job, out)
    tracker = made[0]
    from_people: set[int] = set()
    created: dict[int, tuple[int, int]] = {}
    for index, uv, ids in tracker.created:
        on = on_people(render.people[index], uv)
        from_people.update(ids[on].tolist())
        created[index] = (len(ids), int(on.sum()))
    origin = np.zeros(tracker.map.n_points, bool)
    origin[list(from_people)] = True
    frames = []
    for index, tracked, uv, ids in tracker.record:
        kp_uv, dynamic = tracker.flags[index]
        walker = on_people(render.people[index], kp_uv)
        gt, hit = pixels.get(index, (int(render.people[index].sum()), -1))
        made_all, made_on = created.get(index, (0, 0))
        frames.append(
            FrameRecord(
                index,
                tracked,
                len(kp_uv),
                int(walker.sum()),
                int((walker & dynamic).sum()),
                int((~walker & dynamic).sum()),
                len(ids),
                int(on_people(render.people[index], uv).sum()),
                int(origin[ids].sum()),
                made_all,
                made_on,
                gt,
                hit,
            )
        )
    ate = data.get("ate")
    record = RunRecord(
        render.path.name, model.name, None if ate is None else 1000 * ate["rmse"], frames
    )
    seq = TumSequence(render.path, max_frames=max_frames)
    if seq.groundtruth is not None and (out / "trajectory.txt").is_file():
        traj = read_trajectory(out / "trajectory.txt")
        rel = rpe(seq.groundtruth, traj, delta=window, unit="frames")
        stamps = np.asarray(seq.stamps)
        record.window_rpe_mm = [  # a pair's first pose: the frame nearest its stamp
            (int(np.argmin(np.abs(stamps - s))), 1000 * float(e))
            for s, e in zip(rel.stamps, rel.trans_errors, strict=True)
        ]
    return record


# ----------------------------------------------------------------------------------- figures


def _ratio(num: float, den: float) -> float | None:
    return None if den <= 0 else num / den


def cover(frames: list[FrameRecord]) -> np.ndarray:
    """Per frame with at least :data:`MIN_WALKER_KP` walker keypoints, the share removed."""
    return np.array(
        [f.walker_removed / f.walker for f in frames if f.walker >= MIN_WALKER_KP], float
    )


def summary(run: RunRecord) -> dict[str, Any]:
    """The figures of one run (shares in 0..1; None where nothing was there to count)."""
    fr = run.frames
    n = max(len(fr), 1)
    walker = sum(f.walker for f in fr)
    static = sum(f.keypoints - f.walker for f in fr)
    removed = sum(f.walker_removed for f in fr)
    static_removed = sum(f.static_removed for f in fr)
    kept = sum(f.keypoints - f.walker_removed - f.static_removed for f in fr)
    tracked = [f for f in fr if f.tracked and f.inliers > 0]
    inliers = sum(f.inliers for f in tracked)
    share = np.array([f.on / f.inliers for f in tracked]) if tracked else np.zeros(0)
    c = cover(fr)
    seen = [f for f in fr if f.gt_pixels > 0 and f.hit_pixels >= 0]
    recall = np.array([f.hit_pixels / f.gt_pixels for f in seen]) if seen else np.zeros(0)
    created = sum(f.created for f in fr)
    created_on = sum(f.created_on for f in fr)
    missed_frames = {
        f.index for f in fr if f.walker >= MIN_WALKER_KP and f.walker_removed / f.walker < MISSED
    }
    created_on_missed = sum(f.created_on for f in fr if f.index in missed_frames)
    return {
        "sequence": run.sequence,
        "model": run.model,
        "ate_mm": run.ate_mm,
        "frames": len(fr),
        "tracked": sum(f.tracked for f in fr),
        "walker_kp": walker / n,
        "walker_removed": _ratio(removed, walker),
        "static_removed_kp": static_removed / n,
        "static_removed": _ratio(static_removed, static),
        "walker_share_raw": _ratio(walker, walker + static),
        "walker_share_kept": _ratio(walker - removed, kept),
        "pixel_recall": float(recall.mean()) if len(recall) else None,
        "cover_frames": len(c),
        "cover_missed": float((c < MISSED).mean()) if len(c) else None,
        "cover_covered": float((c >= COVERED).mean()) if len(c) else None,
        "cover_flicker": float(np.abs(np.diff(c)).mean()) if len(c) > 1 else None,
        "inliers": inliers / max(len(tracked), 1),
        "on_pooled": _ratio(sum(f.on for f in tracked), inliers),
        "on_frames_over": int((share > HIGH_SHARE).sum()),
        "from_pooled": _ratio(sum(f.origin for f in tracked), inliers),
        "created_on": _ratio(created_on, created),
        "created_on_in_missed": _ratio(created_on_missed, created_on),
    }


def windows(run: RunRecord, window: int) -> list[dict[str, Any]]:
    """Per window of ``window`` frames starting at each RPE pair: the drift over it (mm) and the
    walkers' share of the inliers of its frames (pooled)."""
    by_index = {f.index: f for f in run.frames}
    out = []
    for start, drift in run.window_rpe_mm:
        fs = [by_index[i] for i in range(start, start + window) if i in by_index]
        inl = sum(f.inliers for f in fs if f.tracked)
        out.append(
            {
                "start": start,
                "rpe_mm": drift,
                "on": _ratio(sum(f.on for f in fs if f.tracked), inl),
                "cover": _ratio(sum(f.walker_removed for f in fs), sum(f.walker for f in fs)),
            }
        )
    return out


def spearman(x: list[float], y: list[float]) -> float | None:
    """Spearman's rank correlation (average ranks for ties); None for fewer than 3 pairs or a
    constant side."""
    if len(x) < 3:
        return None

    def ranks(v: list[float]) -> np.ndarray:
        a = np.asarray(v, float)
        order = np.argsort(a, kind="stable")
        r = np.empty(len(a))
        r[order] = np.arange(len(a), dtype=float)
        for value in np.unique(a):  # ties share their mean rank
            tie = a == value
            r[tie] = r[tie].mean()
        return r

    rx, ry = ranks(x), ranks(y)
    if rx.std() == 0 or ry.std() == 0:
        return None
    return float(np.corrcoef(rx, ry)[0, 1])


def render_figures(render: Render, runs: list[RunRecord]) -> dict[str, Any]:
    """The walkers of a render: frames with walkers, mean area share and median depth over
    those frames, and their share of the keypoints in the run without a filter (if any)."""
    with_people = [i for i, a in render.area.items() if a > 0]
    depths = [render.depth[i] for i in with_people if np.isfinite(render.depth[i])]
    raw = next((summary(r)["walker_share_raw"] for r in runs if r.model == "none"), None)
    return {
        "frames": len(render.area),
        "with_walkers": len(with_people),
        "area": float(np.mean([render.area[i] for i in with_people])) if with_people else 0.0,
        "depth_m": float(np.median(depths)) if depths else None,
        "walker_share_raw": raw,
    }


def _pct(v: float | None) -> str:
    return "—" if v is None else f"{100 * v:.1f}%"


def _num(v: float | None, digits: int = 1) -> str:
    return "—" if v is None else f"{v:.{digits}f}"


def tables(render: Render, runs: list[RunRecord], window: int) -> str:
    """The markdown tables of one sequence."""
    r = render_figures(render, runs)
    lines = [
        f"### `{render.path.name}`",
        "",
        f"{r['frames']} frames, walkers in {r['with_walkers']}: mean area {_pct(r['area'])} of "
        f"the frame, median depth {_num(r['depth_m'], 2)} m, "
        f"{_pct(r['walker_share_raw'])} of the ORB keypoints (no filter).",
        "",
        "| model | ATE [mm] | walker kp / frame | walker kp removed | static kp removed / frame "
        "| static kp removed | walker share of kept kp | pixel recall | missed frames "
        "| covered frames | flicker |",
        "|" + "---|" * 11,
    ]
    sums = [summary(run) for run in runs]
    for s in sums:
        lines.append(
            f"| {s['model']} | {_num(s['ate_mm'])} | {s['walker_kp']:.1f} "
            f"| {_pct(s['walker_removed'])} | {s['static_removed_kp']:.1f} "
            f"| {_pct(s['static_removed'])} | {_pct(s['walker_share_kept'])} "
            f"| {_pct(s['pixel_recall'])} | {_pct(s['cover_missed'])} "
            f"| {_pct(s['cover_covered'])} | {_num(s['cover_flicker'], 2)} |"
        )
    lines += [
        "",
        "| model | tracked | inliers / frame | walker share of inliers "
        f"| frames > {HIGH_SHARE:.0%} | inliers from walker map points "
        "| walker share of new map points | of those, made in missed frames |",
        "|" + "---|" * 8,
    ]
    for s in sums:
        lines.append(
            f"| {s['model']} | {s['tracked']}/{s['frames']} | {s['inliers']:.0f} "
            f"| {_pct(s['on_pooled'])} | {s['on_frames_over']} | {_pct(s['from_pooled'])} "
            f"| {_pct(s['created_on'])} | {_pct(s['created_on_in_missed'])} |"
        )
    per_run = [windows(run, window) for run in runs]
    starts = sorted({w["start"] for ws in per_run for w in ws})
    if starts:
        lines += [
            "",
            f"Drift over each {window}-frame window, mm (walkers' share of the window's inliers):",
            "",
            "| frames | " + " | ".join(run.model for run in runs) + " |",
            "|" + "---|" * (len(runs) + 1),
        ]
        for start in starts:
            cells = []
            for ws in per_run:
                w = next((w for w in ws if w["start"] == start), None)
                cells.append("—" if w is None else f"{w['rpe_mm']:.0f} ({_pct(w['on'])})")
            lines.append(f"| {start}–{start + window} | " + " | ".join(cells) + " |")
        pairs = [(w["on"], w["rpe_mm"]) for ws in per_run for w in ws if w["on"] is not None]
        rho = spearman([p[0] for p in pairs], [p[1] for p in pairs])
        lines += [
            "",
            f"Spearman rank correlation of a window's drift with its walker share of inliers, "
            f"{len(pairs)} windows of {len(runs)} runs: {_num(rho, 2)}",
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="walking_xyz_masks",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--sequence",
        type=Path,
        action="append",
        default=None,
        help="a labelled TUM sequence folder (labels/); repeatable",
    )
    parser.add_argument(
        "--model",
        action="append",
        default=None,
        help="none, labels or NAME=PATH.onnx; repeatable, in the tables' order",
    )
    parser.add_argument(
        "--split",
        nargs="?",
        const=",".join(PARTS),
        default=None,
        metavar="PARTS",
        help="also run parts of each ONNX model's person mask (comma-separated; default all): "
        "walkers (NAME:walkers, its hits), static (NAME:static, its false alarms), moved "
        "(NAME:moved, as many walker pixels as it hits, on the other side of the walkers)",
    )
    parser.add_argument("--max-frames", type=int, help="only the first N frames of each sequence")
    parser.add_argument(
        "--window", type=int, default=30, help="frames per drift window (default: 30, 1 s)"
    )
    parser.add_argument("--workdir", type=Path, help="keep each run's uss-slam outputs here")
    parser.add_argument("--json", type=Path, help="also write the figures and per-frame records")
    args = parser.parse_args(argv)
    try:
        if not args.sequence:
            raise UssSlamError("--sequence: required (a labelled TUM folder)")
        if not args.model:
            raise UssSlamError("--model: required (none, labels or NAME=PATH.onnx)")
        for path in args.sequence:
            if not path.is_dir():
                raise UssSlamError(f"--sequence {path}: no such folder")
        if args.max_frames is not None and args.max_frames < 2:
            raise UssSlamError(f"--max-frames: expected an integer >= 2, got {args.max_frames}")
        if args.window < 1:
            raise UssSlamError(f"--window: expected an integer >= 1, got {args.window}")
        if args.json is not None and not args.json.parent.is_dir():
            raise UssSlamError(f"--json {args.json}: no such folder {args.json.parent}")
        models = [parse_model(spec) for spec in args.model]
        if args.split is not None:
            parts = parse_parts(args.split)
            models = [part for m in models for part in split(m, parts)]
        names = [m.name for m in models]
        if len(set(names)) < len(names):
            raise UssSlamError(f"--model: names must differ, got {', '.join(names)}")
        renders = [read_render(path, args.max_frames) for path in args.sequence]
        with tempfile.TemporaryDirectory(prefix="walking_xyz_masks_") as tmp:
            workdir = args.workdir or Path(tmp)
            workdir.mkdir(parents=True, exist_ok=True)
            results: list[tuple[Render, list[RunRecord]]] = []
            for render in renders:
                runs = []
                for model in models:
                    runs.append(run_model(render, model, workdir, args.window, args.max_frames))
                    s = summary(runs[-1])
                    print(
                        f"{render.path.name} {model.name}: ATE {_num(s['ate_mm'])} mm, walker kp "
                        f"removed {_pct(s['walker_removed'])}, walker share of inliers "
                        f"{_pct(s['on_pooled'])}",
                        file=sys.stderr,
                        flush=True,
                    )
                results.append((render, runs))
    except UssSlamError as err:
        print(f"walking_xyz_masks: error: {err}", file=sys.stderr)
        return 1
    print("\n\n".join(tables(render, runs, args.window) for render, runs in results))
    if args.json:
        payload = {
            render.path.name: {
                "render": render_figures(render, runs),
                "runs": [
                    {
                        **summary(run),
                        "windows": windows(run, args.window),
                        "frames": [vars(f) for f in run.frames],
                    }
                    for run in runs
                ],
            }
            for render, runs in results
        }
        args.json.write_text(json.dumps(payload, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

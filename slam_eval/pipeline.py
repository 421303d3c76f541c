"""One SLAM run over a sequence: segmenter -> ORB front end -> dynamic filters -> tracker -> map.

Every stage is timed per frame (``timing_ms`` holds the mean milliseconds per processed frame of
each module; ``load`` is the time spent *waiting* for the prefetching reader). Keypoint
accounting: ``flagged[name]`` counts the keypoints a filter judged dynamic, ``dropped[name]`` those
it removed that no earlier filter had removed (so the ``dropped`` values add up to
``extracted - kept``).
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from uss_slam.datasets.errors import UssSlamError
from uss_slam.datasets.tum_io import Trajectory

from .filters import DynamicFilter, FilterContext
from .frontend import OrbConfig, OrbExtractor
from .segmentation import Segmenter
from .semantic_map import MapConfig, PointCloud, SemanticMapBuilder
from .sequence import Frame, TumSequence
from .tracker import Tracker, TrackerConfig


class Timer:
    """Accumulates wall time per named module."""

    def __init__(self) -> None:
        self.total: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.total[name] += time.perf_counter() - start

    def mean_ms(self, frames: int) -> dict[str, float]:
        return {k: 1000.0 * v / max(frames, 1) for k, v in self.total.items()}


@dataclass
class FrameLog:
    """Per-frame record: ``keypoints`` extracted, ``kept`` after the filters, ``inliers`` of the
    final pose (0 when not tracked)."""

    index: int
    stamp: float
    tracked: bool
    keypoints: int
    kept: int
    inliers: int
    keyframe: bool
    relocalised: bool


@dataclass
class RunResult:
    """Everything a run produced (the report turns it into files)."""

    sequence: str
    camera: str
    segmenter: str
    filters: list[str]
    trajectory: Trajectory
    frames: int
    tracked: int
    keyframes: int
    map_points: int
    culled_points: int
    relocalisations: int
    lost_events: int
    unmatched_rgb: int
    keypoints: dict[str, object]
    timing_ms: dict[str, float]
    wall_time_s: float
    cloud: PointCloud
    log: list[FrameLog] = field(repr=False, default_factory=list)

    @property
    def tracked_fraction(self) -> float:
        return self.tracked / max(self.frames, 1)

    @property
    def fps(self) -> float:
        return self.frames / self.wall_time_s if self.wall_time_s > 0 else 0.0


@dataclass
class _FilterState:
    dynamic: np.ndarray
    regions: list[np.ndarray]


class SlamPipeline:
    """Runs the harness on one sequence with one filter set."""

    def __init__(
        self,
        sequence: TumSequence,
        segmenter: Segmenter,
        filters: Sequence[DynamicFilter],
        *,
        orb: OrbConfig | None = None,
        tracker: TrackerConfig | None = None,
        semantic_map: MapConfig | None = None,
        prefetch: int = 4,
        progress: bool = True,
        description: str | None = None,
    ) -> None:
        needing = [f.name for f in filters if f.needs_labels]
        probe = getattr(segmenter, "name", "none")
        if needing and probe == "none":
            raise UssSlamError(
                f"filters {needing} need a segmenter; set segmenter=labels (the sequence's "
                "labels/ folder) or an exported model"
            )
        if segmenter.needs_labels and not sequence.load_labels:
            raise UssSlamError(f"segmenter {probe!r} needs the sequence opened with load_labels")
        self.sequence = sequence
        self.segmenter = segmenter
        self.filters = list(filters)
        self.extractor = OrbExtractor(orb or OrbConfig(), sequence.camera)
        self.tracker_config = tracker or TrackerConfig()
        self.map_config = semantic_map or MapConfig()
        self.prefetch = prefetch
        self.progress = progress
        self.description = description or sequence.path.name

    @staticmethod
    def _apply(
        f: DynamicFilter,
        ctx: FilterContext,
        state: _FilterState,
        timer: Timer,
        counts: dict[str, dict[str, int]],
    ) -> None:
        with timer(f"filter.{f.name}"):
            out = f(ctx)
        counts["flagged"][f.name] += int(out.dynamic.sum())
        counts["dropped"][f.name] += int((out.dynamic & ~state.dynamic).sum())
        counts["checked"][f.name] += out.checked
        state.dynamic = state.dynamic | out.dynamic
        ctx.flags[f.name] = out.dynamic
        if f.motion:
            ctx.motion_flags = ctx.motion_flags | out.dynamic
        if out.region is not None:
            state.regions.append(out.region)

    def run(self) -> RunResult:
        timer = Timer()
        extractor = self.extractor
        tracker = Tracker(self.tracker_config, extractor)
        builder = SemanticMapBuilder(self.map_config, extractor)
        names = [f.name for f in self.filters]
        counts = {key: dict.fromkeys(names, 0) for key in ("flagged", "dropped", "checked")}
        extracted = kept = 0
        stamps: list[float] = []
        poses: list[np.ndarray] = []
        log: list[FrameLog] = []
        previous: Frame | None = None
        bar = tqdm(
            total=len(self.sequence),
            desc=self.description,
            unit="frame",
            disable=not self.progress,
            dynamic_ncols=True,
        )
        start = time.perf_counter()
        frames = self.sequence.frames(self.prefetch)
        try:
            while True:
                with timer("load"):
                    frame = next(frames, None)
                if frame is None:
                    break
                with timer("segmentation"):
                    labels = self.segmenter.segment(frame)
                with timer("orb"):
                    features = extractor(frame.gray, frame.depth)
                n = len(features)
                ctx = FilterContext(frame, features, labels, extractor, tracker, previous)
                ctx.motion_flags = np.zeros(n, bool)
                state = _FilterState(np.zeros(n, bool), [])
                for f in self.filters:
                    if f.stage == "pre":
                        self._apply(f, ctx, state, timer, counts)
                with timer("tracking"):
                    result = tracker.track(frame.index, frame.stamp, features, state.dynamic)
                post = [f for f in self.filters if f.stage == "post"]
                if result.pose_wc is not None and post:
                    ctx.pose_wc, ctx.matched = result.pose_wc, result.matched
                    before = state.dynamic.copy()
                    for f in post:
                        self._apply(f, ctx, state, timer, counts)
                    if (state.dynamic & ~before).any() and result.new_keyframe is None:
                        with timer("tracking"):
                            result.pose_wc, result.matched = tracker.drop(
                                result.pose_wc, features, result.matched, state.dynamic
                            )
                        result.inliers = int((result.matched >= 0).sum())
                dynamic, regions = state.dynamic, state.regions
                with timer("mapping"):
                    kf = tracker.finish_frame(frame.index, frame.stamp, result, features, dynamic)
                    if kf is not None:
                        region = np.logical_or.reduce(regions) if regions else None
                        builder.add(kf.pose_wc, frame.rgb, frame.depth, labels, region)
                extracted += n
                kept += int((~dynamic).sum())
                if result.pose_wc is not None:
                    stamps.append(frame.stamp)
                    poses.append(result.pose_wc)
                log.append(
                    FrameLog(
                        frame.index,
                        frame.stamp,
                        result.pose_wc is not None,
                        n,
                        int((~dynamic).sum()),
                        result.inliers,
                        kf is not None,
                        result.relocalised,
                    )
                )
                previous = frame
                bar.update(1)
                bar.set_postfix(
                    tracked=f"{sum(e.tracked for e in log)}/{len(log)}",
                    kf=len(tracker.map.keyframes),
                    refresh=False,
                )
        finally:
            frames.close()
            bar.close()
        wall = time.perf_counter() - start
        count = len(log)
        timing = timer.mean_ms(count)
        timing["total"] = 1000.0 * wall / max(count, 1)
        with timer("map_build"):
            cloud = builder.build()
        trajectory = (
            Trajectory.from_matrices(stamps, np.stack(poses))
            if poses
            else Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)))
        )
        return RunResult(
            sequence=str(self.sequence.path),
            camera=self.sequence.camera_source,
            segmenter=getattr(self.segmenter, "name", type(self.segmenter).__name__),
            filters=names,
            trajectory=trajectory,
            frames=count,
            tracked=sum(e.tracked for e in log),
            keyframes=len(tracker.map.keyframes),
            map_points=tracker.map.n_good,
            culled_points=tracker.map.culled,
            relocalisations=tracker.relocalisations,
            lost_events=tracker.lost_events,
            unmatched_rgb=self.sequence.unmatched_rgb,
            keypoints={
                "extracted": extracted,
                "kept": kept,
                "per_frame": extracted / max(count, 1),
                **counts,
            },
            timing_ms=timing,
            wall_time_s=wall,
            cloud=cloud,
            log=log,
        )

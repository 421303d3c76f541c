"""One SLAM run over a sequence: segmenter -> ORB front end -> dynamic filters -> tracker -> map.

With ``parallel`` (the default) segmentation and ORB extraction of upcoming frames run in the
prefetch threads, next to PNG decoding, while the main thread filters and tracks the current frame
(PSPNet-SLAM likewise runs segmentation in its own thread); results are identical to the serial
order. With ``prefetch_mode="process"`` reading and ORB extraction run in a worker process instead
(:mod:`..frontend.process`), off the GIL that tracking and the back end hold; segmentation stays
in this process's prefetch threads; the results are the same.

Segmentation schedule (``segment``, config key ``segment=every_frame|keyframes``):

- ``"every_frame"``: every frame is segmented, in the prefetch threads concurrently with ORB
  extraction (of the same frame in one worker, of other frames in the others). An
  :class:`~.segmentation.ImageSegmenter` may therefore be called from ``workers`` threads at once:
  its ``infer`` must be thread-safe (onnxruntime's ``InferenceSession.run`` is), or use
  ``slam.workers=1``.
- ``"keyframes"``: only keyframes are segmented, as robust semantic mapping (paper 3) does; in the
  main thread, once tracking has decided that the frame becomes a keyframe and before its
  keypoints create map points (and before it is added to the semantic map). The filters that
  need labels (``semantic``, ``object``) run on those frames only; the others run on every frame.
  Rule for the frames in between: they are tracked with all their keypoints. This is sound
  because tracking only matches keypoints to *map points*, and map points come only from
  keyframes, where people are filtered: a person's keypoints find nothing of theirs in the map,
  and an accidental match to a static point is rejected by RANSAC and the χ² test. The first
  frames, until the first keyframe exists, are segmented too (each is a first-keyframe
  candidate). The segmenter's cost is paid on keyframes only but on the main thread's critical
  path; BENCHMARKS.md ("SLAM harness") measures both schedules' ATE and time.

Timing: ``timing_ms`` holds the mean wall milliseconds per processed frame of each module
(``read`` = PNG reading and decoding in the prefetch thread, ``load`` = time the main thread
*waited* for the next prepared frame; ``total`` = wall time of
the run per frame, so ``1000 / total`` is the end-to-end frame rate) and ``cpu_ms`` the mean CPU
milliseconds of each module's own thread (robust to a busy machine; a segmenter that computes in
a thread pool of its own, as onnxruntime does, shows only its calling thread's share there).
``segmentation`` in both is per *processed* frame; :attr:`RunResult.segmented_frames` and
:attr:`RunResult.segmentation_ms` give the count and the mean wall / CPU ms per *segmented* frame.
Stages a segmenter times itself (its ``stage_times()``, e.g. the dense CRF of
``segmenter.crf=true``) are the rows ``segmentation.<stage>``, included in ``segmentation``.

Back end (``local_ba``, ``loop_closing``: off in this class's constructor, so that a benchmark
names what it runs; ``uss-slam``'s configuration turns both on by default): after each new keyframe, local
bundle adjustment and keyframe culling (:mod:`..mapping.local_mapping`), then loop detection and
correction (:mod:`..mapping.loop_closing`), in the main thread between frames (timed as ``local_ba`` and
``loop_closing``). With the back end on, each frame's pose is kept relative to its reference
keyframe and the trajectory is composed at the end with the keyframes' final poses, as
ORB-SLAM2's ``SaveTrajectoryTUM``, so corrections of the keyframes reach every frame; with it off,
the trajectory is the tracker's pose of each frame, as before.

Keypoint accounting: ``flagged[name]`` counts the keypoints a filter judged dynamic, ``dropped[name]``
those it removed that no earlier filter had removed (so the ``dropped`` values add up to
``extracted - kept``).
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from uss_slam.core.errors import UssSlamError
from uss_slam.core.progress import progress_bar
from uss_slam.core.tum_io import Trajectory

from ..filters.base import DynamicFilter, FilterContext
from ..frontend import process as frontend_process
from ..frontend.orb import Features, OrbConfig, OrbExtractor
from ..geometry import invert
from ..mapping.local_mapping import BundleAdjuster, LocalMapping, LocalMappingConfig, depth_noise_of
from ..mapping.loop_closing import LoopCloser, LoopClosingConfig
from ..products.octomap import OctoMapBuilder, load_pyoctomap
from ..products.semantic_map import MapConfig, PointCloud, SemanticMapBuilder, merge_clouds
from ..scoring.run_result import FrameLog, RunResult
from ..segmenters.base import Segmenter
from ..sequence import Frame, TumSequence, ahead
from ..tracking.tracker import Tracker, TrackerConfig

SEGMENT_SCHEDULES = ("every_frame", "keyframes")
"""Values of ``segment`` (see the module docstring)."""


class Timer:
    """Accumulates wall time and CPU time (of the measuring thread) per named module."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = defaultdict(float)
        self.cpu: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.thread_time()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - wall, time.thread_time() - cpu)

    def add(self, name: str, wall: float, cpu: float) -> None:
        self.wall[name] += wall
        self.cpu[name] += cpu

    def mean_ms(self, frames: int, cpu: bool = False) -> dict[str, float]:
        totals = self.cpu if cpu else self.wall
        return {k: 1000.0 * v / max(frames, 1) for k, v in totals.items()}


@dataclass
class _Prepared:
    """A frame with its segmentation and features, and how long each took (s)."""

    frame: Frame
    labels: np.ndarray | None
    features: Features
    timer: Timer


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
        workers: int = 2,
        parallel: bool = True,
        prefetch_mode: str = "thread",
        segment: str = "every_frame",
        progress: bool = True,
        description: str | None = None,
        local_ba: bool = False,
        loop_closing: bool = False,
        local_ba_params: LocalMappingConfig | None = None,
        loop_closing_params: LoopClosingConfig | None = None,
        sampling_seed: int | None = None,
    ) -> None:
        """``sampling_seed``: perturbs the tracker's RANSAC sampling (a repeated run,
        :mod:`.repeats`); None = the deterministic run. ``prefetch_mode``: ``"thread"`` or
        ``"process"`` (reading and ORB extraction in a worker process, :mod:`..frontend.process`;
        with ``parallel`` and ``prefetch`` > 0 only)."""
        if prefetch_mode not in frontend_process.PREFETCH_MODES:
            raise UssSlamError(
                f"prefetch_mode={prefetch_mode!r}: choose "
                + " or ".join(frontend_process.PREFETCH_MODES)
            )
        if segment not in SEGMENT_SCHEDULES:
            raise UssSlamError(
                f"segment={segment!r}: choose every_frame (segment every frame, concurrently "
                "with ORB extraction) or keyframes (segment keyframes only)"
            )
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
        if self.map_config.octomap:
            load_pyoctomap()  # a missing extra is one clear line before any frame
        self.prefetch = prefetch
        self.workers = workers
        self.parallel = parallel and prefetch > 0
        self.prefetch_mode = prefetch_mode
        self.segment = segment
        self.progress = progress
        self.description = description or sequence.path.name
        self.local_ba = local_ba
        self.loop_closing = loop_closing
        self.local_ba_params = local_ba_params or LocalMappingConfig()
        self.loop_closing_params = loop_closing_params or LoopClosingConfig()
        self.sampling_seed = sampling_seed

    def _prepare(self, frame: Frame) -> _Prepared:
        """Segmentation (``every_frame`` schedule) and ORB extraction of one frame (run in the
        prefetch threads when ``parallel``, so they overlap the tracking of the previous frame)."""
        timer = Timer()
        timer.add("read", *frame.read_time)
        labels = None
        if self.segment == "every_frame":
            labels = self._segment_timed(frame, timer)
        with timer("orb"):
            features = self.extractor(frame.gray, frame.depth)
        return _Prepared(frame, labels, features, timer)

    def _label(self, extracted: frontend_process.Extracted) -> _Prepared:
        """Segmentation (``every_frame`` schedule) of a frame the worker process read and
        extracted (``prefetch_mode="process"``; in the prefetch threads of this process)."""
        frame = extracted.frame
        timer = Timer()
        timer.add("read", *frame.read_time)
        labels = None
        if self.segment == "every_frame":
            labels = self._segment_timed(frame, timer)
        timer.add("orb", *extracted.orb_time)
        return _Prepared(frame, labels, extracted.features, timer)

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

    def _segment_timed(self, frame: Frame, timer: Timer) -> np.ndarray | None:
        """The segmenter on ``frame``, timed as ``segmentation``, with its own stages as
        ``segmentation.<stage>`` (segmenters with a ``stage_times()`` method)."""
        with timer("segmentation"):
            labels = self.segmenter.segment(frame)
        stage_times = getattr(self.segmenter, "stage_times", None)
        if stage_times is not None:
            for stage, (wall, cpu) in stage_times().items():
                timer.add(f"segmentation.{stage}", wall, cpu)
        return labels

    def _segment_now(self, frame: Frame, timer: Timer) -> np.ndarray | None:
        """Segment ``frame`` in the main thread (``keyframes`` schedule)."""
        return self._segment_timed(frame, timer)

    def run(self) -> RunResult:
        timer = Timer()
        extractor = self.extractor
        tracker = Tracker(self.tracker_config, extractor, self.sampling_seed)
        builder = SemanticMapBuilder(self.map_config, extractor)
        octo = OctoMapBuilder(self.map_config, extractor) if self.map_config.octomap else None
        depth_noise, noise_source = depth_noise_of(
            self.local_ba_params, self.sequence.camera.depth_noise
        )
        adjuster = BundleAdjuster(tracker.k, tracker.bf, extractor.sigma2, depth_noise)
        mapper = LocalMapping(self.local_ba_params, adjuster) if self.local_ba else None
        closer = (
            LoopCloser(self.loop_closing_params, tracker, adjuster) if self.loop_closing else None
        )
        backend = mapper is not None or closer is not None
        anchors: list[tuple[int, np.ndarray]] = []
        # With the back end: each keyframe's cloud in its camera frame, placed at the end.
        keyframe_clouds: list[tuple[int, PointCloud]] = []
        names = [f.name for f in self.filters]
        counts = {key: dict.fromkeys(names, 0) for key in ("flagged", "dropped", "checked")}
        extracted = kept = segmented = corrected = 0
        keyframes_only = self.segment == "keyframes"
        stamps: list[float] = []
        poses: list[np.ndarray] = []
        no_depth: list[int] = []
        """Frames whose depth image holds no valid pixel (untracked, warned about)."""
        log: list[FrameLog] = []
        previous: Frame | None = None
        bar = progress_bar(
            total=len(self.sequence),
            desc=self.description,
            unit="frame",
            disable=not self.progress,
            dynamic_ncols=True,
        )
        start = time.perf_counter()
        worker = None
        if self.parallel and self.prefetch_mode == "process":
            worker = frontend_process.start(
                self.sequence, extractor.config, self.prefetch, self.workers
            )
        if worker is not None:
            frames = ahead(self._label, iter(worker), self.prefetch, self.workers)
        elif self.parallel:
            frames = self.sequence.prepared(self._prepare, self.prefetch, self.workers)
        else:
            frames = (self._prepare(f) for f in self.sequence.frames(self.prefetch, self.workers))
        try:
            while True:
                with timer("load"):
                    item = next(frames, None)
                if item is None:
                    break
                for name in item.timer.wall:
                    timer.add(name, item.timer.wall[name], item.timer.cpu[name])
                frame, labels, features = item.frame, item.labels, item.features
                if keyframes_only and not tracker.initialized:
                    labels = self._segment_now(frame, timer)  # a first-keyframe candidate
                raw = features
                if tracker.readout > 0:
                    with timer("tracking"):
                        features = tracker.unroll(raw)
                n = len(features)
                ctx = FilterContext(frame, features, labels, extractor, tracker, previous)
                ctx.motion_flags = np.zeros(n, bool)
                state = _FilterState(np.zeros(n, bool), [])
                # Filters needing labels wait for them (keyframes schedule: until a keyframe).
                ready = [f for f in self.filters if labels is not None or not f.needs_labels]
                for f in ready:
                    if f.stage == "pre":
                        self._apply(f, ctx, state, timer, counts)
                with timer("tracking"):
                    result = tracker.track(frame.index, frame.stamp, features, state.dynamic)
                    if not np.any(frame.depth > 0):
                        # No depth at all: a pose from 2D matches alone would be a silent guess.
                        no_depth.append(frame.index)
                        if result.pose_wc is not None:
                            tracker.mark_lost(result)
                    if tracker.readout > 0:
                        features = ctx.features = tracker.unroll_tracked(
                            raw, features, frame.stamp, result
                        )
                        corrected += features is not raw
                post = [f for f in ready if f.stage == "post"]
                late: list[DynamicFilter] = []
                keyframe: bool | None = None
                if keyframes_only and labels is None and result.pose_wc is not None:
                    with timer("mapping"):
                        keyframe = tracker.wants_keyframe(result, features, state.dynamic)
                    if keyframe:
                        labels = ctx.labels = self._segment_now(frame, timer)
                        if labels is not None:
                            late = [f for f in self.filters if f.needs_labels]
                if result.pose_wc is not None and (post or late):
                    ctx.pose_wc, ctx.matched = result.pose_wc, result.matched
                    before = state.dynamic.copy()
                    for f in post + late:
                        self._apply(f, ctx, state, timer, counts)
                    if (state.dynamic & ~before).any() and result.new_keyframe is None:
                        with timer("tracking"):
                            pose_wc, result.matched = tracker.refine_without(
                                result.pose_wc, features, result.matched, state.dynamic
                            )
                            if pose_wc is None:  # failed its inlier check: lost, not mapped
                                tracker.mark_lost(result)
                            result.pose_wc = pose_wc
                        result.inliers = int((result.matched >= 0).sum())
                segmented += labels is not None
                dynamic, regions = state.dynamic, state.regions
                with timer("mapping"):
                    kf = tracker.finish_frame(
                        frame.index, frame.stamp, result, features, dynamic, keyframe
                    )
                    if kf is not None:
                        kf.depth = frame.depth[:: kf.depth_stride, :: kf.depth_stride].copy()
                        region = np.logical_or.reduce(regions) if regions else None
                        if backend:  # the keyframe may still move: keep its cloud in its frame
                            own = SemanticMapBuilder(self.map_config, extractor)
                            own.add(np.eye(4), frame.rgb, frame.depth, labels, region)
                            keyframe_clouds.append((kf.id, own.build()))
                        else:
                            builder.add(kf.pose_wc, frame.rgb, frame.depth, labels, region)
                        if octo is not None:
                            octo.add(kf.id, frame.rgb, frame.depth, labels, region)
                if result.pose_wc is not None and backend:
                    anchor = tracker.anchor()
                    assert anchor is not None
                    anchors.append(anchor)
                if kf is not None and kf.id > 0 and backend:
                    if mapper is not None:
                        with timer("local_ba"):
                            mapper.process(tracker.map, kf.id)
                    if closer is not None:
                        with timer("loop_closing"):
                            closer.process(kf)
                    tracker.map_changed()
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
            if worker is not None:
                worker.close()
            bar.close()
        wall = time.perf_counter() - start
        if no_depth:
            print(
                f"uss-slam: warning: {self.sequence.path}: {len(no_depth)} frame(s) with an "
                f"all-zero depth image (frame index {no_depth[0]} first) were not tracked",
                file=sys.stderr,
            )
        count = len(log)
        timing = timer.mean_ms(count)
        timing["total"] = 1000.0 * wall / max(count, 1)
        cpu = timer.mean_ms(count, cpu=True)
        cpu.pop("load", None)
        per_segmented = (
            {
                "wall": 1000.0 * timer.wall["segmentation"] / segmented,
                "cpu": 1000.0 * timer.cpu["segmentation"] / segmented,
            }
            if segmented
            else {}
        )
        with timer("map_build"):
            if backend:
                placed = []
                for kf_id, c in keyframe_clouds:
                    pose = tracker.map.pose_wc(kf_id)
                    points = (c.points @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32)
                    placed.append(PointCloud(points, c.colors, c.labels))
                cloud = merge_clouds(placed, self.map_config.voxel)
            else:
                cloud = builder.build()
        with timer("octomap"):  # every keyframe at its final pose
            octomap = octo.build(tracker.map.pose_wc) if octo is not None else None
        if backend:  # ORB-SLAM2's SaveTrajectoryTUM: each frame on its keyframe's final pose
            poses = [tracker.map.pose_wc(k) @ invert(rel) for k, rel in anchors]
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
            cpu_ms=cpu,
            wall_time_s=wall,
            cloud=cloud,
            log=log,
            segment=self.segment,
            segmented_frames=segmented,
            segmentation_ms=per_segmented,
            segmentation_thread="prefetch" if self.parallel and not keyframes_only else "main",
            local_ba=(
                {
                    **mapper.stats.as_dict(),
                    "depth_noise": depth_noise,
                    "depth_noise_from": noise_source,
                }
                if mapper is not None
                else None
            ),  # fmt: skip
            rolling_shutter={
                "readout": tracker.readout,
                "readout_from": tracker.readout_from,
                "frames_corrected": corrected,
            },
            loop_closing=closer is not None,
            loop_closures=[c.as_dict() for c in closer.closures] if closer is not None else [],
            loop_candidates_rejected=closer.rejected if closer is not None else 0,
            octomap=octomap,
        )

"""One SLAM run over a sequence: segmenter -> ORB front end -> dynamic filters -> tracker -> map.

With ``parallel`` (the default) segmentation and ORB extraction of upcoming frames run in the
prefetch threads, next to PNG decoding, while the main thread filters and tracks the current frame
(PSPNet-SLAM likewise runs segmentation in its own thread); results are identical to the serial
order. With ``prefetch_mode="process"`` reading and ORB extraction run in a worker process instead
(:mod:`..frontend.process`), off the GIL that tracking and the back end hold; segmentation, and
the depth images the worker leaves to this process, stay in this process's prefetch threads; the
results are the same.

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
- ``"thread"``: as RDS-SLAM, keyframes are segmented in a semantic thread off the tracking
  path; tracking never waits for a mask; each frame is filtered with the latest mask carried to
  it by its tracked pose, and each mask marks bad the map points its keyframe saw inside the
  dynamic region (:mod:`.semantic_thread`, which also says how a segmenter's latency is
  simulated on the camera clock or spent on the wall clock).

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
from collections.abc import Iterator, Sequence

import numpy as np

from uss_slam.core.errors import UssSlamError
from uss_slam.core.progress import progress_bar
from uss_slam.core.tum_io import Trajectory

from ..filters.base import DynamicFilter
from ..filters.chain import FilterChain
from ..frontend import process as frontend_process
from ..frontend.orb import OrbConfig, OrbExtractor
from ..frontend.pools import one_thread_pools
from ..geometry import invert
from ..map.slam_map import SlamMap
from ..mapping.local_mapping import LocalMapping, LocalMappingConfig, depth_noise_of
from ..mapping.loop_closing import LoopCloser, LoopClosingConfig
from ..optim.local_ba import BundleAdjuster
from ..products.builder import MapProducts
from ..products.octomap import load_pyoctomap
from ..products.semantic_map import MapConfig
from ..scoring.run_result import RunResult
from ..segmenters.base import Segmenter
from ..sequence import Frame, TumSequence, ahead
from ..tracking.tracker import Tracker, TrackerConfig
from .frame_loop import FrameLoop, Prepared, Timer
from .late_mask import final_ba_runs
from .semantic_thread import (
    CARRY_RADIUS_M,
    CARRY_RADIUS_MIN_INLIERS,
    MASK_MARKS_PROJECTED,
    MASK_MAX_AGE_S,
    MASK_REFINES_PAST_DEFAULT,
    start_thread,
)

SEGMENT_SCHEDULES = ("every_frame", "keyframes", "thread")
"""Values of ``segment`` (see the module docstring)."""


def _check_settings(
    sequence: TumSequence,
    segmenter: Segmenter,
    filters: Sequence[DynamicFilter],
    prefetch_mode: str,
    segment: str,
    provisional_points: bool,
) -> None:
    """One line (:class:`UssSlamError`) for a combination :class:`SlamPipeline` cannot run."""
    if prefetch_mode not in frontend_process.PREFETCH_MODES:
        raise UssSlamError(
            f"prefetch_mode={prefetch_mode!r}: choose "
            + ", ".join(frontend_process.PREFETCH_MODES[:-1])
            + " or " + frontend_process.PREFETCH_MODES[-1]
        )  # fmt: skip
    if segment not in SEGMENT_SCHEDULES:
        raise UssSlamError(
            f"segment={segment!r}: choose every_frame (segment every frame, concurrently "
            "with ORB extraction), keyframes (segment keyframes only) or thread (keyframes "
            "in a semantic thread off the tracking path)"
        )
    for line in (
        provisional_points_refused(provisional_points, segment),
        simulated_latency_refused(segmenter, segment),
    ):
        if line is not None:
            raise UssSlamError(line)
    needing = [f.name for f in filters if f.needs_labels]
    probe = getattr(segmenter, "name", "none")
    if needing and probe == "none":
        raise UssSlamError(
            f"filters {needing} need a segmenter; set segmenter=labels (the sequence's "
            "labels/ folder) or an exported model"
        )
    if segmenter.needs_labels and not sequence.load_labels:
        raise UssSlamError(f"segmenter {probe!r} needs the sequence opened with load_labels")


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
        reader_threads: int | None = 1,
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
        provisional_points: bool = False,
        provisional_border_px: int | None = None,
        semantic_nice: int = 0,
        carry_to_keyframes: str = "none",
        carry_velocity: bool = False,
        carry_radius_m: float | None = CARRY_RADIUS_M,
        carry_radius_keypoints: str = "all",
        carry_radius_min_inliers: int = CARRY_RADIUS_MIN_INLIERS,
        mask_refines_past: str = MASK_REFINES_PAST_DEFAULT,
        mask_marks_projected: bool = MASK_MARKS_PROJECTED,
        mask_refits_keyframes: bool = False,
        mask_refit_min_observations: int = 0,
        mask_max_age_s: float | None = MASK_MAX_AGE_S,
        final_ba: str = "none",
    ) -> None:
        """``sampling_seed``: perturbs the tracker's RANSAC sampling (a repeated run,
        :mod:`.repeats`); None = the deterministic run. ``prefetch_mode``: ``"thread"``,
        ``"process"`` (reading and ORB extraction in a worker process, :mod:`..frontend.process`;
        with ``parallel`` and ``prefetch`` > 0 only) or ``"auto"`` (the process where the run
        has a core to spare: :func:`..frontend.process.resolve_mode`); ``reader_threads``: the
        worker process's reading and extracting threads (None: ``workers``)."""
        _check_settings(sequence, segmenter, filters, prefetch_mode, segment, provisional_points)
        self.sequence = sequence
        self.segmenter = segmenter
        self.filters = list(filters)
        self.extractor = OrbExtractor(orb or OrbConfig(), sequence.camera)
        self.tracker_config = tracker or TrackerConfig()
        self.map_config = semantic_map or MapConfig()
        if self.map_config.octomap:
            load_pyoctomap()  # a missing extra is one clear line before any frame
        self.prefetch, self.workers = prefetch, workers
        self.reader_threads = reader_threads
        self.parallel = parallel and prefetch > 0
        self.prefetch_mode = prefetch_mode
        """As given; ``auto`` is resolved as each run starts (:attr:`mode_used`)."""
        self.mode_used: str | None = None
        """``thread`` or ``process``: where the last run read and extracted its frames."""
        self.segment = segment
        self.semantic_nice = semantic_nice
        self.loop_keys = dict(
            provisional_points=provisional_points, provisional_border_px=provisional_border_px,
            carry_to_keyframes=carry_to_keyframes, carry_velocity=carry_velocity,
            carry_radius_m=carry_radius_m, carry_radius_keypoints=carry_radius_keypoints,
            carry_radius_min_inliers=carry_radius_min_inliers, mask_max_age_s=mask_max_age_s,
            mask_refines_past=mask_refines_past, mask_marks_projected=mask_marks_projected,
            mask_refits_keyframes=mask_refits_keyframes,
            refit_min_observations=mask_refit_min_observations,
            final_ba=final_ba_runs(final_ba, segment),
        )  # fmt: skip
        """The semantic thread's keys and the end-of-run pass, as :class:`FrameLoop` takes them."""
        self.progress = progress
        self.description = description or sequence.path.name
        self.local_ba, self.loop_closing = local_ba, loop_closing
        self.local_ba_params = local_ba_params or LocalMappingConfig()
        self.loop_closing_params = loop_closing_params or LoopClosingConfig()
        self.depth_noise = depth_noise_of(self.local_ba_params, sequence.camera.depth_noise)
        """``(k, where it came from)``: the depth noise local BA models (:func:`depth_noise_of`)."""
        self.sampling_seed = sampling_seed

    def _prepare(self, frame: Frame) -> Prepared:
        """Segmentation (``every_frame`` schedule) and ORB extraction of one frame (run in the
        prefetch threads when ``parallel``, so they overlap the tracking of the previous frame)."""
        timer = Timer()
        timer.add("read", *frame.read_time)
        labels = None
        if self.segment == "every_frame":
            labels = self._segment_timed(frame, timer)
        with timer("orb"):
            features = self.extractor(frame.gray, frame.depth)
        return Prepared(frame, labels, features, timer)

    def _label(self, received: frontend_process.Received) -> Prepared:
        """A frame the worker process read and extracted (``prefetch_mode="process"``), in the
        prefetch threads of this process: its images out of the shared ring, its depth and label
        images (read here unless the worker read them), the depth sampled at the keypoints, and
        its segmentation (``every_frame`` schedule)."""
        got = received.take()
        timer = Timer()
        depth, given = got.depth, got.labels
        if depth is None:  # the worker leaves them to this process unless this one is behind
            with timer("read"):
                depth, given = self.sequence.load_depth_and_labels(got.index)
        timer.add("read", *got.read_time)
        frame = Frame(got.index, got.stamp, got.rgb, got.gray, depth, given,
                      (timer.wall["read"], timer.cpu["read"]))  # fmt: skip
        with timer("orb"):
            features = self.extractor.with_depth(got.features, depth)
        timer.add("orb", *got.orb_time)
        labels = None
        if self.segment == "every_frame":
            labels = self._segment_timed(frame, timer)
        return Prepared(frame, labels, features, timer)

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

    def run(self) -> RunResult:
        """Every frame of the sequence through the frame loop (:mod:`.frame_loop`), then the
        trajectory, the map products and the run's figures; with one thread in OpenBLAS's and
        OpenCV's pools (theirs would spin on the cores the run's own threads use:
        :mod:`..frontend.pools`)."""
        with one_thread_pools():
            return self._run()

    def _run(self) -> RunResult:
        timer = Timer()
        loop = self._frame_loop(timer)
        bar = progress_bar(
            total=len(self.sequence),
            desc=self.description,
            unit="frame",
            disable=not self.progress,
            dynamic_ncols=True,
        )
        start = time.perf_counter()
        worker, frames = self._frames()
        try:
            while True:
                with timer("load"):
                    item = next(frames, None)
                if item is None:
                    break
                loop.step(item)
                bar.update(1)
                bar.set_postfix(
                    tracked=f"{loop.counts['tracked']}/{len(loop.log)}",
                    kf=len(loop.map.keyframes),
                    refresh=False,
                )
            wall = time.perf_counter() - start  # the frames' rate, without the end-of-run pass
            loop.finish()
        finally:
            frames.close()
            if loop.semantic is not None:
                loop.semantic.close()
            if worker is not None:
                worker.close()
            bar.close()
        return self._result(loop, wall)

    def _frame_loop(self, timer: Timer) -> FrameLoop:
        """The run's tracker, filter chain, map products and back end, in a frame loop."""
        extractor = self.extractor
        slam_map = SlamMap(extractor.config.scale_factor, extractor.config.n_levels)
        tracker = Tracker(self.tracker_config, extractor, self.sampling_seed, slam_map)
        adjuster = BundleAdjuster(tracker.k, tracker.bf, extractor.sigma2, self.depth_noise[0])
        mapper = LocalMapping(self.local_ba_params, adjuster) if self.local_ba else None
        closer = None
        if self.loop_closing:
            closer = LoopCloser(
                self.loop_closing_params, slam_map, tracker.projection, tracker.sampler, adjuster
            )
        backend = mapper is not None or closer is not None
        products = MapProducts(self.map_config, extractor, placed_at_end=backend)
        segment_now = self._segment_timed if self.segment == "keyframes" else None
        chain = FilterChain(self.filters, timer)
        semantic = (
            start_thread(self.segmenter, self.semantic_nice) if self.segment == "thread" else None
        )
        return FrameLoop(
            timer, tracker, slam_map, chain, products, mapper, closer, segment_now, semantic,
            **self.loop_keys,
        )  # fmt: skip

    def _frames(self) -> tuple[frontend_process.FrontendProcess | None, Iterator[Prepared]]:
        """The prepared frames in order (threads, or a worker process with ``prefetch_mode=
        "process"``, or serially), and that worker (None without one)."""
        worker = None
        if self.parallel and frontend_process.resolve_mode(self.prefetch_mode) == "process":
            threads = self.workers if self.reader_threads is None else self.reader_threads
            worker = frontend_process.start(
                self.sequence, self.extractor.config, self.prefetch, threads
            )
        self.mode_used = "thread" if worker is None else "process"
        if worker is not None:
            frames = ahead(self._label, iter(worker), self.prefetch, self.workers)
        elif self.parallel:
            frames = self.sequence.prepared(self._prepare, self.prefetch, self.workers)
        else:
            frames = (self._prepare(f) for f in self.sequence.frames(self.prefetch, self.workers))
        return worker, frames

    def _result(self, loop: FrameLoop, wall: float) -> RunResult:
        """The run's :class:`RunResult` from its frame loop (``wall``: seconds of the loop)."""
        if loop.no_depth:
            print(
                f"uss-slam: warning: {self.sequence.path}: {len(loop.no_depth)} frame(s) with an "
                f"all-zero depth image (frame index {loop.no_depth[0]} first) were not tracked",
                file=sys.stderr,
            )
        count = len(loop.log)
        timer, tracker, mapper, closer = loop.timer, loop.tracker, loop.mapper, loop.closer
        timing = timer.mean_ms(count)
        timing["total"] = 1000.0 * wall / max(count, 1)
        cpu = timer.mean_ms(count, cpu=True)
        cpu.pop("load", None)
        with timer("map_build"):
            cloud = loop.products.build_cloud(loop.map.pose_wc)
        with timer("octomap"):  # every keyframe at its final pose
            octomap = loop.products.build_octomap(loop.map.pose_wc)
        noise = dict(zip(("depth_noise", "depth_noise_from"), self.depth_noise, strict=True))
        thread, segmented, per_segmented, semantic = self._segmentation(loop)
        return RunResult(
            sequence=str(self.sequence.path),
            camera=self.sequence.camera_source,
            segmenter=getattr(self.segmenter, "name", type(self.segmenter).__name__),
            filters=loop.chain.names,
            trajectory=self._trajectory(loop),
            frames=count,
            tracked=loop.counts["tracked"],
            keyframes=len(loop.map.keyframes),
            map_points=loop.map.n_good,
            culled_points=loop.map.culled,
            relocalisations=tracker.relocalisations,
            lost_events=tracker.lost_events,
            unmatched_rgb=self.sequence.unmatched_rgb,
            keypoints={
                "extracted": loop.counts["extracted"],
                "kept": loop.counts["kept"],
                "per_frame": loop.counts["extracted"] / max(count, 1),
                **loop.chain.counts,
            },
            timing_ms=timing,
            cpu_ms=cpu,
            wall_time_s=wall,
            cloud=cloud,
            log=loop.log,
            segment=self.segment,
            segmented_frames=segmented,
            segmentation_ms=per_segmented,
            segmentation_thread=thread,
            semantic_thread=semantic,
            local_ba=None if mapper is None else {**mapper.stats.as_dict(), **noise},
            rolling_shutter={
                "readout": tracker.readout,
                "readout_from": tracker.readout_from,
                "frames_corrected": loop.counts["corrected"],
            },
            loop_closing=closer is not None,
            loop_closures=[c.as_dict() for c in closer.closures] if closer is not None else [],
            loop_candidates_rejected=closer.rejected if closer is not None else 0,
            octomap=octomap,
        )

    def _segmentation(
        self, loop: FrameLoop
    ) -> tuple[str, int, dict[str, float], dict[str, float | int | str] | None]:
        """Where the segmenter ran, the frames segmented (masks delivered by the semantic
        thread), the mean ms per segmented frame and the semantic thread's figures (None
        without it), for :class:`RunResult`."""
        thread = "prefetch" if self.parallel and self.segment == "every_frame" else "main"
        segmented = loop.counts["segmented"]
        if loop.semantic is None:
            return thread, segmented, _per_segmented(loop.timer, segmented), None
        stats = loop.semantic.stats
        per_segmented = {}
        if loop.semantic.clock == "wall" and stats.delivered:
            per_segmented = {"wall": 1000.0 * stats.segment_s / stats.delivered}
        semantic = {
            "clock": loop.semantic.clock,
            **stats.as_dict(),
            "points_marked": loop.counts["points_marked"],
            **{
                k: loop.counts[k]
                for k in (
                    "points_held",
                    "points_cleared",
                    "points_dropped",
                    "keyframes_gated",
                    "keyframes_carried",
                    "points_marked_carried",
                    "people_moving",
                    "keypoints_near_people",
                    "frames_radius_skipped",
                    "past_frames_refined",
                    "points_marked_projected",
                    "observations_erased_carried",
                    "keyframes_refit_skipped",
                    "frame_masks",
                    "final_ba_outliers",
                )  # fmt: skip
                if k in loop.counts
            },
        }
        return "semantic", loop.counts["masks"], per_segmented, semantic

    @staticmethod
    def _trajectory(loop: FrameLoop) -> Trajectory:
        """The tracked frames' poses; with the back end, each frame on its reference keyframe's
        final pose (ORB-SLAM2's ``SaveTrajectoryTUM``)."""
        poses = loop.poses
        if loop.backend:
            pose_wc = loop.map.pose_wc
            poses = [pose_wc(k) @ invert(rel) for k, rel in loop.anchors]
        if not poses:
            return Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)))
        return Trajectory.from_matrices(loop.stamps, np.stack(poses))


def simulated_latency_refused(segmenter: object, segment: str) -> str | None:
    """One line when ``segmenter`` has a simulated latency (> 0) that ``segment`` cannot
    simulate (only ``thread`` can), else None."""
    latency = getattr(segmenter, "simulated_latency_s", None)
    if latency and segment != "thread":
        return (
            f"segmenter.latency_s={latency:g} is simulated by segment=thread only; with "
            f"segment={segment} set segmenter.wait=true (every call then really waits)"
        )
    return None


def provisional_points_refused(provisional_points: bool, segment: str) -> str | None:
    """One line when ``slam.provisional_points`` is on with a ``segment`` schedule other than
    ``thread`` (the only one whose keyframes wait for a mask), else None."""
    if provisional_points and segment != "thread":
        return f"slam.provisional_points=true needs segment=thread (got segment={segment})"
    return None


def _per_segmented(timer: Timer, segmented: int) -> dict[str, float]:
    """``{"wall": ms, "cpu": ms}`` of the segmenter per segmented frame ({} for none)."""
    if not segmented:
        return {}
    return {
        "wall": 1000.0 * timer.wall["segmentation"] / segmented,
        "cpu": 1000.0 * timer.cpu["segmentation"] / segmented,
    }

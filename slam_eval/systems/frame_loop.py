"""The frame loop of one harness run (:class:`~.harness.SlamPipeline`), one method per step.

Per frame (:meth:`FrameLoop.step`), on a frame already read, segmented (``every_frame``) and
ORB-extracted by the prefetch:

1. **track** (:meth:`FrameLoop.track`): the ``pre`` filters (:mod:`..filters.chain`), the
   tracker's pose, and the rolling-shutter passes; then (:meth:`FrameLoop.filter_tracked`) the
   keyframe's segmentation (``segment=keyframes``), the ``post`` / ``late`` filters and the
   pose refined again without what they flagged;
2. **map keyframe** (:meth:`FrameLoop.map_keyframe`): motion model, map statistics, the keyframe
   decision and its map points, and the keyframe in the map products (:mod:`..products`);
3. **back end** (:meth:`FrameLoop.back_end`): the frame's pose on its reference keyframe, local
   bundle adjustment and loop closing after a new keyframe;
4. **record** (:meth:`FrameLoop.record`): keypoint counts, the tracked pose and the frame's log.

With ``segment=thread`` (:mod:`.semantic_thread`) the frames before the first keyframe wait for
their own labels (:meth:`FrameLoop.first_mask`); each frame first takes the masks the semantic
thread finished (:meth:`FrameLoop.receive`), the latest one is carried to the tracked frame and
filters it at the ``late`` stage, and a new keyframe is handed to the thread after step 2.

Timing names (``tracking``, ``mapping``, ``local_ba``, ``loop_closing``, ``filter.<name>``,
``segmentation``, ``carry_mask``) are those of the harness's ``timing_ms``.
"""

from __future__ import annotations

import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..filters.base import FilterContext
from ..filters.chain import FilterChain, FrameFilters
from ..frontend.orb import Features
from ..geometry import invert
from ..map.slam_map import KeyFrame, SlamMap
from ..mapping.local_mapping import LocalMapping
from ..mapping.loop_closing import LoopCloser
from ..products.builder import MapProducts
from ..scoring.run_result import FrameLog
from ..sequence import Frame
from ..tracking.tracker import Tracker, TrackResult
from .late_mask import (
    PAST_FRAMES,
    PastFrame,
    adjust_all,
    erase_carried,
    refine_frames,
    since_previous,
)
from .mask_points import hold_new_points, mark_projected, settle_provisional
from .semantic_thread import (
    CarriedMask,
    Delivered,
    SemanticThread,
    carry_targets,
    classes_near,
    frame_mask,
    mark_carried,
    mark_dynamic_points,
    people_motion,
)


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
class Prepared:
    """A frame with its segmentation and features, and how long each took (s)."""

    frame: Frame
    labels: np.ndarray | None
    features: Features
    timer: Timer


Segment = Callable[[Frame, Timer], "np.ndarray | None"]
"""Segments a frame in the main thread, timed (``segment=keyframes``)."""


@dataclass
class FrameLoop:
    """The state of one run's frame loop and its steps (module docstring). ``segment_now``:
    the main-thread segmenter of the ``keyframes`` schedule, None for ``every_frame``."""

    timer: Timer
    tracker: Tracker
    map: SlamMap
    """The run's map, the harness's, shared by the tracker, the back end and the filters."""
    chain: FilterChain
    products: MapProducts
    mapper: LocalMapping | None
    closer: LoopCloser | None
    segment_now: Segment | None
    semantic: SemanticThread | None = None
    """The semantic thread of ``segment=thread`` (:mod:`.semantic_thread`), else None."""
    carried: CarriedMask | None = None
    """With the semantic thread: the latest mask delivered, carried to each later frame."""
    provisional_points: bool = False
    """With the semantic thread (``slam.provisional_points``): the map points of a keyframe made
    without a mask are held back (bad) until a mask clears them
    (:func:`~.mask_points.settle_provisional`), and while every point the newest keyframe
    held back is still waiting, a frame becomes a keyframe only when the tracker wants one and
    ``max_keyframe_interval`` frames have passed since the last (:meth:`keyframe_gate`)."""
    provisional_border_px: int | None = None
    """With ``provisional_points`` (``slam.provisional_border_px``): hold back only the new
    points whose keypoint lies within this many pixels of the carried mask's dynamic region
    (:meth:`near_carried`), without the keyframe gate; None: all of them, with the gate."""
    carry_to_keyframes: str = "none"
    """With the semantic thread (``slam.carry_to_keyframes``): the other keyframes each delivered
    mask is carried to, to mark their points too (:func:`~.semantic_thread.carry_targets`)."""
    last_masked: int | None = None
    """The keyframe id of the last mask delivered (None: none yet)."""
    carry_velocity: bool = False
    """With the semantic thread (``slam.carry_velocity``): the carried mask is also drawn where
    each person moves to (:func:`~.semantic_thread.people_motion`)."""
    carry_radius_m: float | None = None
    """With the semantic thread (``slam.carry_radius_m``): a keypoint whose 3D point lies within
    this many metres of the carried mask's points is flagged with them (:meth:`paint_near`)."""
    carry_radius_keypoints: str = "all"
    """With ``carry_radius_m`` (``slam.carry_radius_keypoints``): ``all`` keypoints near the
    carried people, or only those the tracker did not match (``untracked``)."""
    carry_radius_min_inliers: int = 0
    """With ``carry_radius_m`` (``slam.carry_radius_min_inliers``): a frame keeping fewer pose
    inliers outside the radius is not flagged by it (0: always flagged)."""
    mask_refines_past: str = "none"
    """With the semantic thread (``slam.mask_refines_past``): a delivered mask also corrects the
    past (:meth:`refine_past`): ``points``, the past the map points it marked steered; ``mask``,
    also the frames' keypoints it flags carried back to them; ``none``, nothing."""
    mask_marks_projected: bool = False
    """With the semantic thread (``slam.mask_marks_projected``): a delivered mask also marks bad
    the points mapped since the previous mask's keyframe that project into its dynamic region
    (:func:`~.mask_points.mark_projected`)."""
    mask_refits_keyframes: bool = False
    """With ``mask_refines_past`` (``slam.mask_refits_keyframes``): a delivered mask is also
    carried back to the keyframes made since the previous mask's keyframe, their observations
    inside it erased, and local BA runs again with them free (:func:`~.late_mask.erase_carried`)."""
    refit_min_observations: int = 0
    """With ``mask_refits_keyframes`` (``slam.mask_refit_min_observations``): a keyframe that
    would keep fewer observations is not refit (``keyframes_refit_skipped``)."""
    final_ba: bool = False
    """``slam.final_ba`` (:meth:`finish`): the end-of-run bundle adjustment of the whole map."""
    mask_max_age_s: float | None = None
    """With the semantic thread (``slam.mask_max_age_s``): a frame is segmented itself when the
    carried mask is older than this (s) and the thread is idle (:meth:`refresh_mask`)."""
    past: list[PastFrame] = field(default_factory=list)
    """With ``mask_refines_past``: the tracked frames (keyframes' own frames excepted) since the
    keyframe of the mask before the last one delivered, at most :data:`PAST_FRAMES`."""
    people: tuple[np.ndarray, float] | None = None
    """With ``carry_velocity``: the last delivered mask's people, ``(B, 3)`` map-frame
    centroids and its stamp (s)."""
    provisional: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """The (P,) ids of the map points held back and not judged by a mask yet."""
    pending: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """The ids the newest keyframe held back (empty: none, or the keyframe was not held)."""
    anchors: list[tuple[int, np.ndarray]] = field(default_factory=list)
    """With the back end: each tracked frame's ``(reference keyframe id, T_c,kf)``."""
    stamps: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    """The tracked frames' stamps (s) and (4, 4) camera-to-world poses as tracked."""
    no_depth: list[int] = field(default_factory=list)
    """Frames whose depth image holds no valid pixel (untracked, warned about)."""
    log: list[FrameLog] = field(default_factory=list)
    previous: Frame | None = None
    counts: Counter[str] = field(default_factory=Counter)
    """Over the run: ``extracted`` keypoints (after the first rolling-shutter pass), ``kept``
    (of those, flagged by no filter); frames ``segmented`` (with labels when mapped),
    ``corrected`` (by the second rolling-shutter pass), ``tracked`` (with a pose); with the
    semantic thread, ``masks`` delivered and map ``points_marked`` bad by them."""

    @property
    def backend(self) -> bool:
        """Local mapping or loop closing is on."""
        return self.mapper is not None or self.closer is not None

    def step(self, item: Prepared) -> None:
        """One frame through every step."""
        timer = self.timer
        for name in item.timer.wall:
            timer.add(name, item.timer.wall[name], item.timer.cpu[name])
        frame, labels = item.frame, item.labels
        first = not self.tracker.initialized
        if self.segment_now is not None and first:
            labels = self.segment_now(frame, timer)  # a first-keyframe candidate
        if self.semantic is not None:
            self.receive(frame.stamp)
            if first:
                labels = self.first_mask(frame)
        filters, result = self.track(frame, labels, item.features)
        matched = result.matched  # before the carried mask's flags are dropped
        keyframe = self.filter_tracked(frame, filters, result)
        if self.provisional_points and self.provisional_border_px is None and keyframe is None:
            keyframe = self.keyframe_gate(filters, result)
        kf = self.map_keyframe(frame, filters, result, keyframe)
        if self.semantic is not None and kf is not None:
            if first and labels is not None:  # the map starts from a masked frame
                self.carried = CarriedMask.of(
                    kf.id, labels, frame.depth, self.tracker.k, frame.stamp
                )
                self.last_masked = kf.id
                self.track_people()
            else:
                self.semantic.request(frame, kf.id)  # returns at once
                if self.provisional_points:
                    held = hold_new_points(self.map, kf.id, self.near_carried(filters))
                    self.provisional = np.concatenate([self.provisional, held])
                    self.pending = held
                    self.counts["points_held"] += len(held)
        elif self.semantic is not None and result.pose_wc is not None:
            self.refresh_mask(frame, filters.ctx.features, matched)
        self.back_end(result, kf, frame.stamp)
        self.record(frame, filters, result, kf)

    def track(
        self, frame: Frame, labels: np.ndarray | None, raw: Features
    ) -> tuple[FrameFilters, TrackResult]:
        """The ``pre`` filters and the tracker on the frame's keypoints ``raw`` (corrected for
        the rolling shutter first, and again once tracked: ``ctx.features`` holds the keypoints
        the rest of the frame uses). A frame without any depth is taken back (lost)."""
        tracker, timer = self.tracker, self.timer
        features = raw
        if tracker.readout > 0:
            with timer("tracking"):
                features = tracker.unroll(raw)
        ctx = FilterContext(frame, features, labels, tracker.extractor, self.map, self.previous)
        filters = self.chain.frame(ctx)
        filters.pre()
        with timer("tracking"):
            result = tracker.track(frame.index, frame.stamp, features, filters.dynamic)
            if not np.any(frame.depth > 0):
                # No depth at all: a pose from 2D matches alone would be a silent guess.
                self.no_depth.append(frame.index)
                if result.pose_wc is not None:
                    tracker.mark_lost(result)
            if tracker.readout > 0:
                ctx.features = tracker.unroll_tracked(raw, features, frame.stamp, result)
                self.counts["corrected"] += ctx.features is not raw
        return filters, result

    def filter_tracked(
        self, frame: Frame, filters: FrameFilters, result: TrackResult
    ) -> bool | None:
        """The ``post`` filters on a tracked frame, and with ``segment=keyframes`` the keyframe
        decision taken now, so that a new keyframe is segmented and its ``late`` filters run
        before its map points are created; the pose is refined again without what they
        flagged (lost if too few inliers remain). Returns the keyframe decision (None: not
        taken yet)."""
        tracker, timer, ctx = self.tracker, self.timer, filters.ctx
        keyframe: bool | None = None
        late = False
        if self.carried is not None and ctx.labels is None and result.pose_wc is not None:
            with timer("carry_mask"):
                ctx.labels = self.carried.labels_for(self.map, result.pose_wc, frame.stamp)
                self.paint_near(ctx.labels, ctx.features, result)
            late = True
        elif self.segment_now is not None and ctx.labels is None and result.pose_wc is not None:
            with timer("mapping"):
                keyframe = tracker.wants_keyframe(result, ctx.features, filters.dynamic)
            if keyframe:
                ctx.labels = self.segment_now(frame, timer)
                late = ctx.labels is not None
        if filters.after_pose(result.pose_wc, result.matched, late) and result.new_keyframe is None:
            with timer("tracking"):
                pose_wc, result.matched = tracker.refine_without(
                    result.pose_wc, ctx.features, result.matched, filters.dynamic
                )
                if pose_wc is None:  # failed its inlier check: lost, not mapped
                    tracker.mark_lost(result)
                result.pose_wc = pose_wc
            result.inliers = int((result.matched >= 0).sum())
        return keyframe

    def keyframe_gate(self, filters: FrameFilters, result: TrackResult) -> bool | None:
        """With provisional points: None (the tracker decides) unless the newest keyframe is
        still waiting, i.e. every point it held back is still provisional (no mask has judged
        any); then the tracker's decision (:meth:`~.Tracker.wants_keyframe`) only once
        ``max_keyframe_interval`` frames have passed since the last keyframe, else False. Held
        points are not matched, so without this gate a keyframe that holds its points back
        seems to track few and asks for the next keyframe at once, which holds its own back."""
        pending = self.pending
        if len(pending) == 0 or not np.isin(pending, self.provisional).all():
            return None
        tracker = self.tracker
        if tracker.frames_since_keyframe + 1 < tracker.config.max_keyframe_interval:
            self.counts["keyframes_gated"] += tracker.wants_keyframe(
                result, filters.ctx.features, filters.dynamic
            )
            return False
        return None

    def near_carried(self, filters: FrameFilters) -> np.ndarray | None:
        """With ``provisional_border_px``: ``(H, W)`` bool, the dynamic region of the labels
        carried to this frame (the filters that mask their input) grown by that many pixels
        (all False without carried labels); None without the border (every new point held)."""
        border = self.provisional_border_px
        if border is None:
            return None
        ctx = filters.ctx
        region = self.dynamic_region(ctx.frame, ctx.labels)
        if region is None:
            return np.zeros(ctx.frame.gray.shape, bool)
        if border == 0 or not region.any():
            return region
        # pixels within ``border`` (Euclidean) of the region, at any border in O(H W)
        away = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, 5)
        return away <= border

    def first_mask(self, frame: Frame) -> np.ndarray | None:
        """With the semantic thread, a first-keyframe candidate's labels: tracking waits for
        them (:meth:`~.semantic_thread.SemanticThread.wait_for`), so that the map starts
        without the people in view."""
        assert self.semantic is not None
        with self.timer("segmentation"):
            labels = self.semantic.wait_for(frame)
        self.counts["masks"] += labels is not None
        return labels

    def receive(self, stamp: float) -> None:
        """The semantic thread's masks finished by camera ``stamp`` (s): each marks bad the map
        points its keyframe sees inside the dynamic region of the filters that mask their input
        (:func:`~.semantic_thread.mark_dynamic_points`) and becomes the carried mask."""
        assert self.semantic is not None
        with self.timer("carry_mask"):
            for got in self.semantic.poll(stamp):
                if got.labels is None:
                    continue
                self.counts["masks"] += 1
                if got.anchor is not None:  # a frame's own mask (:meth:`refresh_mask`)
                    region = self.dynamic_region(got.frame, got.labels)
                    self.carried, marked = frame_mask(self.map, got, region, self.tracker.k)
                    self.counts["points_marked"] += marked
                    self.counts["frame_masks"] += 1
                    continue
                slam_map = self.map
                region = self.dynamic_region(got.frame, got.labels)
                carried = CarriedMask.of(
                    got.kf_id, got.labels, got.frame.depth, self.tracker.k, got.frame.stamp
                )
                if region is not None:
                    self.mark(got, region, carried)
                    if self.provisional_points:
                        self.provisional, cleared, dropped = settle_provisional(
                            slam_map,
                            self.provisional,
                            got.kf_id,
                            region,
                            got.frame.depth,
                            self.tracker.k,
                        )
                        self.counts["points_cleared"] += cleared
                        self.counts["points_dropped"] += dropped
                self.carried = carried
                self.track_people()
                self.carry_to_others(got.frame, got.kf_id)

    def refresh_mask(self, frame: Frame, features: Features, matched: np.ndarray) -> None:
        """With ``mask_max_age_s``: the tracked ``frame``, no keyframe, asks the idle thread for
        its own mask once the carried one is older than that (its keypoints ``features`` were
        matched to ``matched`` (N,) map points before the refine; :func:`~.semantic_thread.
        frame_mask` delivers it)."""
        limit, semantic = self.mask_max_age_s, self.semantic
        assert semantic is not None
        if limit is None or (
            self.carried is not None and frame.stamp - self.carried.stamp <= limit
        ):
            return
        anchor = self.tracker.anchor()
        if anchor is not None and semantic.idle():
            semantic.request_frame(frame, anchor, features.xy, matched)

    def mark(self, got: Delivered, region: np.ndarray, carried: CarriedMask) -> None:
        """The map points keyframe ``got.kf_id`` observes inside its mask's dynamic ``region``
        (H, W) marked bad (:func:`~.semantic_thread.mark_dynamic_points`); with
        ``mask_marks_projected`` also the unjudged points projecting into it
        (:func:`~.mask_points.mark_projected`, ``points_marked_projected``); with
        ``mask_refines_past`` the past they steered corrected (:meth:`refine_past`; ``carried``:
        the mask ready to be carried)."""
        slam_map = self.map
        refine = self.mask_refines_past
        before = slam_map.points.bad.view.copy() if refine != "none" else None
        marked = mark_dynamic_points(slam_map, got.kf_id, region)
        self.counts["points_marked"] += marked
        if self.mask_marks_projected and self.last_masked is not None:
            depth, k = got.frame.depth, self.tracker.k
            projected = mark_projected(slam_map, got.kf_id, region, depth, k, self.last_masked)
            self.counts["points_marked_projected"] += projected
            marked += projected
        if before is not None and (marked or refine == "mask"):
            self.refine_past(got, ~before & slam_map.points.bad.view, carried)

    def refine_past(self, got: Delivered, marked: np.ndarray, carried: CarriedMask) -> None:
        """Keyframe ``got.kf_id``'s late mask just marked the map points ``marked`` ((P,) bool)
        bad: local BA around it again without them (:meth:`~..mapping.local_mapping.
        LocalMapping.readjust`), then each past frame that was tracked on any of them (``mask``:
        or on a keypoint that the mask ``carried`` to the frame by its pose flags) gets its pose
        refined on its other matches in the map as it is now (kept where enough inliers remain,
        :meth:`~..tracking.tracker.Tracker.refine_without`) and put back on its reference
        keyframe, so that the trajectory loses the error they caused, not only what would come.
        Frames older than the previous mask's keyframe are forgotten first. Counted as
        ``past_frames_refined``."""
        slam_map, tracker, kf_id = self.map, self.tracker, got.kf_id
        if self.last_masked is not None:
            since = slam_map.keyframes[self.last_masked].stamp
            self.past = [p for p in self.past if p.stamp >= since]
        targets, erased = [], 0
        if self.mask_refits_keyframes:
            targets = since_previous(slam_map, kf_id, self.last_masked)
            floor = self.refit_min_observations
            region_of = lambda labels: self.dynamic_region(got.frame, labels)  # noqa: E731
            erased, kept = erase_carried(slam_map, carried, targets, region_of, floor)
            self.counts["observations_erased_carried"] += erased
            self.counts["keyframes_refit_skipped"] += len(targets) - len(kept)
            targets = kept
        if (
            self.mapper is not None
            and (marked.any() or erased)
            and not slam_map.keyframes[kf_id].bad
        ):
            with self.timer("local_ba"):
                self.mapper.readjust(slam_map, kf_id, np.array(targets, np.int64))
        region_of = None
        if self.mask_refines_past == "mask":
            region_of = lambda labels: self.dynamic_region(got.frame, labels)  # noqa: E731
        anchors = self.anchors if self.backend else None
        self.counts["past_frames_refined"] += refine_frames(
            slam_map, tracker, self.past, self.poses, anchors, carried, region_of
        )
        tracker.map_changed()

    def finish(self) -> None:
        """After the last frame, with ``final_ba`` and local BA: the semantic thread's masks still
        in flight delivered (the camera clock's as to a frame two latencies after the last, by
        when both the running and the waiting one are done; the wall clock's that are done),
        then one bundle adjustment of the whole map (:func:`~.late_mask.adjust_all`, timed as
        ``final_ba``), before the trajectory is composed on the keyframes."""
        if not self.final_ba or self.mapper is None:
            return
        if self.semantic is not None and self.log:
            self.receive(self.log[-1].stamp + 2 * self.semantic.latency_s)
        with self.timer("final_ba"):
            done = adjust_all(self.map, self.mapper.adjuster)
        self.counts["final_ba_outliers"] += done.outliers

    def track_people(self) -> None:
        """With ``carry_velocity``: the people of the mask just carried move as they did since
        the mask before (:func:`~.semantic_thread.people_motion`)."""
        if self.carry_velocity and self.carried is not None:
            pose = self.carried.source_pose(self.map)
            self.people = people_motion(self.carried, pose, self.people)
            carried = self.carried
            assert carried.velocity is not None and carried.region is not None
            moving = np.any(carried.velocity != 0, axis=1)
            self.counts["people_moving"] += len(np.unique(carried.region[moving]))

    def paint_near(self, labels: np.ndarray, features: Features, result: TrackResult) -> None:
        """With ``carry_radius_m``: paint into the carried ``labels`` (H, W) the class of each
        keypoint whose 3D point lies that near a carried point
        (:func:`~.semantic_thread.classes_near`; with ``carry_radius_keypoints="untracked"``
        only the keypoints ``result`` matched to no map point), at its pixel, so that the
        filters flag it; counted as ``keypoints_near_people``. Not on a frame that would keep
        fewer than ``carry_radius_min_inliers`` pose inliers (``frames_radius_skipped``)."""
        if not self.carry_radius_m or self.carried is None or result.pose_wc is None:
            return
        t_frame_kf = invert(result.pose_wc) @ self.carried.source_pose(self.map)
        cls = classes_near(self.carried, t_frame_kf, features.points, self.carry_radius_m)
        if self.carry_radius_keypoints == "untracked" and result.matched is not None:
            cls[result.matched >= 0] = 0
        floor = self.carry_radius_min_inliers if result.matched is not None else 0
        if floor and int(((result.matched >= 0) & (cls == 0)).sum()) < floor:
            self.counts["frames_radius_skipped"] += 1
            return
        near = np.flatnonzero(cls)
        h, w = labels.shape
        col = np.clip(np.rint(features.xy[near, 0]).astype(np.int64), 0, w - 1)
        row = np.clip(np.rint(features.xy[near, 1]).astype(np.int64), 0, h - 1)
        fresh = labels[row, col] == 0
        labels[row, col] = np.where(fresh, cls[near], labels[row, col])
        self.counts["keypoints_near_people"] += int(fresh.sum())

    def dynamic_region(self, frame: Frame, labels: np.ndarray | None) -> np.ndarray | None:
        """``(H, W)`` bool: the union of the dynamic regions that the filters which mask their
        input find in ``frame``'s ``labels`` (H, W); None when none of them does."""
        regions = [
            f.input_region(frame, labels)
            for f in self.chain.filters
            if f.needs_labels and f.masks_input
        ]
        regions = [r for r in regions if r is not None]
        return np.logical_or.reduce(regions) if regions else None

    def carry_to_others(self, frame: Frame, kf_id: int) -> None:
        """The mask just delivered for keyframe ``kf_id`` (``self.carried``) carried to the
        keyframes ``carry_to_keyframes`` names, marking their points inside it
        (:func:`~.semantic_thread.mark_carried`); counted as ``keyframes_carried`` and
        ``points_marked_carried``."""
        targets = carry_targets(self.map, kf_id, self.last_masked, self.carry_to_keyframes)
        self.last_masked = kf_id
        if not targets or self.carried is None:
            return
        self.counts["keyframes_carried"] += len(targets)
        self.counts["points_marked_carried"] += mark_carried(
            self.map, self.carried, targets, lambda labels: self.dynamic_region(frame, labels)
        )

    def map_keyframe(
        self, frame: Frame, filters: FrameFilters, result: TrackResult, keyframe: bool | None
    ) -> KeyFrame | None:
        """The tracker's end of the frame (motion model, map statistics, the keyframe decision
        and its map points); a new keyframe keeps its subsampled depth (the geometry filter's)
        and goes into the map products without the filters' dynamic region."""
        ctx = filters.ctx
        self.counts["segmented"] += ctx.labels is not None
        with self.timer("mapping"):
            kf = self.tracker.finish_frame(
                frame.index, frame.stamp, result, ctx.features, filters.dynamic, keyframe
            )
            if kf is not None:
                kf.depth = frame.depth[:: kf.depth_stride, :: kf.depth_stride].copy()
                self.products.add(kf, frame, ctx.labels, filters.region())
        return kf

    def back_end(self, result: TrackResult, kf: KeyFrame | None, stamp: float) -> None:
        """With the back end: the tracked frame's pose kept on its reference keyframe, and
        after a new keyframe (not the first) local bundle adjustment (now, or once the mapper's
        busy time is over: ``local_ba_params.min_interval_s``), loop closing and the tracker's
        last pose put back on the corrected map."""
        if not self.backend:
            return
        tracker = self.tracker
        if result.pose_wc is not None:
            anchor = tracker.anchor()
            assert anchor is not None
            self.anchors.append(anchor)
        if kf is None or kf.id == 0:
            if self.mapper is not None and self.mapper.waiting is not None:
                with self.timer("local_ba"):
                    if self.mapper.frame(self.map, stamp):
                        tracker.map_changed()
            return
        if self.mapper is not None:
            with self.timer("local_ba"):
                self.mapper.keyframe(self.map, kf.id, stamp)
        if self.closer is not None:
            with self.timer("loop_closing"):
                self.closer.process(kf)
        tracker.map_changed()

    def record(
        self, frame: Frame, filters: FrameFilters, result: TrackResult, kf: KeyFrame | None
    ) -> None:
        """The frame's keypoint counts, its pose (when tracked) and its :class:`FrameLog`."""
        n = len(filters.ctx.features)
        kept = int((~filters.dynamic).sum())
        self.counts["extracted"] += n
        self.counts["kept"] += kept
        tracked = result.pose_wc is not None
        if tracked:
            if self.mask_refines_past != "none" and kf is None and result.matched is not None:
                features = filters.ctx.features
                self.past.append(
                    PastFrame(len(self.stamps), frame.stamp, features, result.matched.copy())
                )
                del self.past[:-PAST_FRAMES]
            self.stamps.append(frame.stamp)
            self.poses.append(result.pose_wc)
        self.counts["tracked"] += tracked
        self.log.append(
            FrameLog(
                frame.index, frame.stamp, tracked, n, kept, result.inliers, kf is not None,
                result.relocalised,
            )
        )  # fmt: skip
        self.previous = frame

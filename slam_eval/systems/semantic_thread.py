"""The semantic thread of ``segment=thread`` (as RDS-SLAM): keyframes are segmented off the
tracking path, tracking never waits for a mask, and the frames in between are filtered with the
latest mask carried to them by the tracked pose. The one wait: until the map exists, each frame's
labels are segmented in the main thread (:meth:`SemanticThread.wait_for`), so that the first
keyframe maps no person; its mask is the first carried one.

Per frame (:class:`~.frame_loop.FrameLoop`): the masks that finished since the last frame are
taken (:meth:`SemanticThread.poll`, never blocking); each one marks the map points its keyframe
sees inside the dynamic region as bad (:func:`mark_dynamic_points`: tracking no longer matches
them, so a person mapped before its mask came back stops steering the pose; by default also the
points mapped since the previous mask that project into it, :func:`.mask_points.mark_projected`), corrects
the frames tracked since the previous mask's keyframe
(:meth:`~.frame_loop.FrameLoop.refine_past`) and becomes the mask that is carried (:class:`CarriedMask`) (with ``slam.carry_to_keyframes``, also to the
keyframes that got no mask of their own, marking their points: :func:`mark_carried`); once the
frame is tracked, the carried labels
(:meth:`CarriedMask.labels_at`: the keyframe's labelled pixels, back-projected with its depth,
holes filled by :func:`fill_depth`, and projected with the frame's tracked pose) feed the filters that need labels, and the pose is
refined without what they flagged (the ``late`` stage of :mod:`..filters.chain`). A new keyframe
is then handed to the thread (:meth:`SemanticThread.request`). One segmentation runs at a time;
a keyframe that arrives while one runs waits, replaced by any newer one (the newest keyframe is
the one worth segmenting).

Two clocks:

- **camera** (:class:`SimulatedThread`, for a segmenter with a simulated latency: the ``labels``
  oracle with ``latency_s`` and ``wait=false``): the labels are computed at once, but a
  segmentation started at camera stamp ``t`` is delivered to the first frame whose stamp is at
  least ``t + latency_s``; the next one starts when it ends. Frames are taken to arrive at their
  stamps and to be tracked at camera rate, so the delivery frames, and therefore the
  trajectory, are deterministic (the same on a loaded machine).
- **wall** (:class:`WallThread`, every other segmenter, and ``labels`` with ``wait=true``): a real
  Python thread calls the segmenter; a mask is delivered to the first frame polled after it
  finished. This is the figure of the tracking rate with the segmenter's cost in the loop; the
  trajectory then depends on the machine's speed.
"""

from __future__ import annotations

import atexit
import os
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..filters.base import values_at
from ..geometry import invert
from ..map.slam_map import SlamMap
from ..segmenters.base import Segmenter
from ..sequence import Frame

CARRY_STRIDE = 4
"""Pixel step of the carried mask's grid (each carried pixel is splatted over this step)."""


@dataclass
class Delivered:
    """A keyframe's mask: ``kf_id``, its frame, its ``(H, W)`` uint8 labels (None: the segmenter
    gave none), and ``requested`` / ``delivered``: the stamps (s) of the frame that asked and of
    the frame that received it. A tracked frame's own mask (``slam.mask_max_age_s``,
    :meth:`SemanticThread.request_frame`) has ``kf_id`` -1 and ``anchor``, the frame's
    reference keyframe and ``T_c,kf`` (4, 4) as tracked; ``xy`` (N, 2) its keypoints' pixels and
    ``matched`` (N,) the map point each was matched to (-1 none)."""

    kf_id: int
    frame: Frame
    labels: np.ndarray | None
    requested: float
    delivered: float = 0.0
    anchor: tuple[int, np.ndarray] | None = None
    xy: np.ndarray | None = None
    matched: np.ndarray | None = None


@dataclass
class ThreadStats:
    """Over a run: keyframes ``requested``, ``frames`` asked for themselves (no keyframe,
    ``slam.mask_max_age_s``), ``skipped`` (replaced by a newer one while waiting), masks
    ``delivered``, their summed ``delay_s`` (delivery stamp - request stamp) and ``segment_s``
    (wall time inside the segmenter, wall clock only)."""

    requested: int = 0
    frames: int = 0
    skipped: int = 0
    delivered: int = 0
    delay_s: float = 0.0
    segment_s: float = 0.0
    first_wait_s: float = 0.0

    def as_dict(self) -> dict[str, float | int]:
        n = max(self.delivered, 1)
        return {
            "requested": self.requested,
            "frames_requested": self.frames,
            "skipped": self.skipped,
            "delivered": self.delivered,
            "mean_delay_s": self.delay_s / n,
            "mean_segment_s": self.segment_s / n,
            "first_wait_s": self.first_wait_s,
        }


class SemanticThread:
    """What both clocks share: the waiting keyframe (newest wins) and the statistics."""

    clock = "none"
    latency_s = 0.0

    def __init__(self, segmenter: Segmenter) -> None:
        self.segmenter = segmenter
        self.stats = ThreadStats()
        self._pending: Delivered | None = None

    def request(self, frame: Frame, kf_id: int) -> None:
        """Ask for keyframe ``kf_id`` (of ``frame``) to be segmented; returns at once."""
        self.stats.requested += 1
        self._ask(Delivered(kf_id, frame, None, frame.stamp))

    def request_frame(
        self, frame: Frame, anchor: tuple[int, np.ndarray], xy: np.ndarray, matched: np.ndarray
    ) -> None:
        """Ask for a tracked ``frame`` that is no keyframe to be segmented (``Delivered``'s
        ``anchor``, ``xy``, ``matched``); returns at once."""
        self.stats.frames += 1
        self._ask(Delivered(-1, frame, None, frame.stamp, anchor=anchor, xy=xy, matched=matched))

    def idle(self) -> bool:
        """Nothing is being segmented and nothing waits."""
        return self._pending is None

    def _ask(self, item: Delivered) -> None:
        if self._pending is not None:
            self.stats.skipped += 1
        self._pending = item

    def poll(self, stamp: float) -> list[Delivered]:
        """The masks finished by camera stamp ``stamp`` (s), oldest first; never waits."""
        raise NotImplementedError

    def wait_for(self, frame: Frame) -> np.ndarray | None:
        """``frame``'s labels, segmented now in the calling thread (the one wait of a run:
        the first keyframe's mask); counted as delivered with the segmenter's latency."""
        start = time.perf_counter()
        labels = self.segmenter.segment(frame)
        waited = time.perf_counter() - start
        self.stats.first_wait_s += waited if self.clock == "wall" else self.latency_s
        return labels

    def close(self) -> None:
        """Stop (a segmentation under way is abandoned)."""

    def _deliver(self, item: Delivered, stamp: float) -> Delivered:
        item.delivered = stamp
        self.stats.delivered += 1
        self.stats.delay_s += stamp - item.requested
        return item


class SimulatedThread(SemanticThread):
    """The camera clock (module docstring): ``latency_s`` of camera time per segmentation."""

    clock = "camera"

    def __init__(self, segmenter: Segmenter, latency_s: float) -> None:
        super().__init__(segmenter)
        self.latency_s = float(latency_s)
        self._running: tuple[float, Delivered] | None = None  # (done at, item)

    def _ask(self, item: Delivered) -> None:
        super()._ask(item)
        if self._running is None:
            self._start(item.requested)

    def idle(self) -> bool:
        return self._running is None and super().idle()

    def _start(self, at: float) -> None:
        item, self._pending = self._pending, None
        if item is not None:
            item.labels = self.segmenter.segment(item.frame)
            self._running = (at + self.latency_s, item)

    def poll(self, stamp: float) -> list[Delivered]:
        out = []
        while self._running is not None and self._running[0] <= stamp + 1e-9:
            done_at, item = self._running
            self._running = None
            out.append(self._deliver(item, stamp))
            self._start(done_at)  # the next waiting keyframe starts when this one ends
        return out


class WallThread(SemanticThread):
    """The wall clock (module docstring): a daemon thread runs the segmenter."""

    clock = "wall"

    def __init__(self, segmenter: Segmenter, nice: int = 0) -> None:
        super().__init__(segmenter)
        self.nice = int(nice)
        self._lock = threading.Condition()
        self._done: list[Delivered] = []
        self._stop = False
        self._busy = False
        self._thread = threading.Thread(target=self._work, name="semantic", daemon=True)
        self._thread.start()
        _UNDER_WAY.add(self._thread)

    def _ask(self, item: Delivered) -> None:
        with self._lock:
            super()._ask(item)
            self._lock.notify()

    def idle(self) -> bool:
        with self._lock:
            return not self._busy and super().idle()

    def _work(self) -> None:
        if self.nice > 0:
            lower_priority(self.nice)
        while True:
            with self._lock:
                while self._pending is None and not self._stop:
                    self._lock.wait()
                if self._stop:
                    return
                item, self._pending = self._pending, None
                self._busy = True
            start = time.perf_counter()
            item.labels = self.segmenter.segment(item.frame)
            with self._lock:
                self.stats.segment_s += time.perf_counter() - start
                self._done.append(item)
                self._busy = False

    def poll(self, stamp: float) -> list[Delivered]:
        with self._lock:
            done, self._done = self._done, []
        return [self._deliver(item, stamp) for item in done]

    def close(self) -> None:
        with self._lock:
            self._stop = True
            self._lock.notify()
        self._thread.join(timeout=0.1)  # a segmentation under way ends on its own (daemon)


_UNDER_WAY: weakref.WeakSet[threading.Thread] = weakref.WeakSet()
"""Every :class:`WallThread`'s thread: a segmentation under way when its run ended goes on in
the background, and is waited for before the interpreter exits (:func:`_finish_segmentations`)."""

EXIT_WAIT_S = 120.0
"""How long the interpreter's exit waits for each segmentation still under way (s)."""


@atexit.register
def _finish_segmentations() -> None:
    """Wait for the segmentations still running in abandoned semantic threads: a native
    segmenter (onnxruntime) still computing while the interpreter tears down its runtime aborts
    the process (``terminate called without an active exception``), after the run's outputs
    were written."""
    for thread in list(_UNDER_WAY):
        thread.join(timeout=EXIT_WAIT_S)


def lower_priority(nice: int) -> None:
    """Raise the calling thread's own nice value by ``nice`` (Linux schedules threads on their
    own; elsewhere, or where refused, nothing changes). The segmenter runs in this thread (with
    one intra-op thread onnxruntime computes in the caller), so tracking and its prefetch take
    the cores first and the network the time they leave."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
    except (AttributeError, OSError):
        pass


def start_thread(segmenter: Segmenter, nice: int = 0) -> SemanticThread:
    """The semantic thread for ``segmenter``: the camera clock when it declares a
    ``simulated_latency_s`` (not None), else the wall clock (its thread ``nice`` more nice than
    the process: :func:`lower_priority`)."""
    latency = getattr(segmenter, "simulated_latency_s", None)
    if latency is not None:
        return SimulatedThread(segmenter, float(latency))
    return WallThread(segmenter, nice)


MIN_PERSON_POINTS = 20
"""A connected labelled region of the carried grid counts as a person (its own velocity) from
this many grid points on (:func:`people_motion`)."""

MAX_PERSON_SPEED = 1.5
"""A person's velocity is capped at this speed (m/s), and a region of the previous mask farther
than this speed times the time between the masks is not the same person."""

MAX_EXTRAPOLATION_S = 1.0
"""The carried mask is moved by a person's velocity for at most this long (s)."""


@dataclass
class CarriedMask:
    """A keyframe's labels ready to be carried: the labelled pixels of a ``CARRY_STRIDE`` grid
    with depth, as ``points`` (M, 3) metres in the keyframe's camera frame and ``classes`` (M,)
    uint8, nearest last (so that the nearest wins where several land on one pixel); ``region``
    (M,) the connected labelled region of the grid each point lies in, ``stamp`` the keyframe's
    (s) and ``velocity`` (M, 3) m/s in the keyframe's camera frame (None: not moved;
    :func:`people_motion`)."""

    kf_id: int
    points: np.ndarray
    classes: np.ndarray
    shape: tuple[int, int]
    k: np.ndarray = field(repr=False)
    region: np.ndarray | None = field(default=None, repr=False)
    stamp: float = 0.0
    velocity: np.ndarray | None = field(default=None, repr=False)
    anchor: tuple[int, np.ndarray] | None = field(default=None, repr=False)

    @classmethod
    def of(
        cls, kf_id: int, labels: np.ndarray, depth: np.ndarray, k: np.ndarray, stamp: float = 0.0,
        anchor: tuple[int, np.ndarray] | None = None,
    ) -> CarriedMask:  # fmt: skip
        """From ``(H, W)`` uint8 ``labels`` and ``(H, W)`` float ``depth`` (m, 0 = none) of
        keyframe ``kf_id`` at ``stamp`` (s); ``k`` (3, 3) the camera matrix. A frame's own mask
        (``kf_id`` -1) is carried from ``anchor`` (:meth:`source_pose`)."""
        s = CARRY_STRIDE
        lab = labels[::s, ::s]
        z = depth[::s, ::s]
        z = fill_depth(lab, z)
        rows, cols = np.nonzero((lab > 0) & (z > 0))
        zz = z[rows, cols].astype(np.float64)
        u, v = cols * s, rows * s
        pts = np.stack([(u - k[0, 2]) * zz / k[0, 0], (v - k[1, 2]) * zz / k[1, 1], zz], axis=1)
        order = np.argsort(-zz, kind="stable")
        _, comp = cv2.connectedComponents((lab > 0).astype(np.uint8), connectivity=8)
        region = comp[rows, cols][order]
        classes = lab[rows, cols][order]
        return cls(kf_id, pts[order], classes, labels.shape, k, region, stamp, anchor=anchor)

    def source_pose(self, slam_map: SlamMap) -> np.ndarray:
        """The camera-to-world pose (4, 4) the mask is carried from, as the map holds it now:
        its keyframe's, or a frame's own mask's reference keyframe's composed with ``T_c,kf``."""
        if self.anchor is None:
            return slam_map.pose_wc(self.kf_id)
        kf_id, t_c_kf = self.anchor
        return slam_map.pose_wc(kf_id) @ invert(t_c_kf)

    def labels_at(self, t_frame_kf: np.ndarray, dt: float = 0.0) -> np.ndarray:
        """``(H, W)`` uint8 labels carried to a frame whose pose relative to the keyframe is
        ``t_frame_kf`` (4, 4, ``T_frame,kf``) ``dt`` s after it: each point projected, splatted
        over the grid step; with a ``velocity``, also each point moved by it for ``dt`` (at most
        :data:`MAX_EXTRAPOLATION_S`); 0 where nothing lands."""
        h, w = self.shape
        out = np.zeros((h, w), np.uint8)
        if len(self.points) == 0:
            return out
        points, classes = self.points, self.classes
        if self.velocity is not None and dt > 0:
            moved = points + self.velocity * min(dt, MAX_EXTRAPOLATION_S)
            points, classes = np.concatenate([points, moved]), np.concatenate([classes, classes])
            order = np.argsort(-points[:, 2], kind="stable")  # nearest last again
            points, classes = points[order], classes[order]
        p = points @ t_frame_kf[:3, :3].T + t_frame_kf[:3, 3]
        front = p[:, 2] > 1e-6
        p, cls = p[front], classes[front]
        u = np.rint(self.k[0, 0] * p[:, 0] / p[:, 2] + self.k[0, 2]).astype(np.int64)
        v = np.rint(self.k[1, 1] * p[:, 1] / p[:, 2] + self.k[1, 2]).astype(np.int64)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        out[v[inside], u[inside]] = cls[inside]  # the last (nearest) wins
        kernel = np.ones((CARRY_STRIDE + 1, CARRY_STRIDE + 1), np.uint8)
        grown = cv2.dilate(out, kernel)
        return np.where(out > 0, out, grown)

    def labels_for(
        self, slam_map: SlamMap, pose_wc: np.ndarray, stamp: float | None = None
    ) -> np.ndarray:
        """The labels carried to a frame at camera-to-world ``pose_wc`` (4, 4) and ``stamp``
        (s; None: the keyframe's), from the keyframe's pose in ``slam_map`` now (the back end
        may have moved it)."""
        dt = 0.0 if stamp is None else stamp - self.stamp
        return self.labels_at(invert(pose_wc) @ self.source_pose(slam_map), dt)


CARRY_RADIUS_M: float | None = 0.3
"""``slam.carry_radius_m``'s default: a keypoint whose 3D point lies within this many metres of
the carried mask's people is flagged with them (:func:`classes_near`), on a frame that keeps
:data:`CARRY_RADIUS_MIN_INLIERS` pose inliers outside it."""

CARRY_RADIUS_MIN_INLIERS = 100
"""``slam.carry_radius_min_inliers``'s default (docs/results/slam.md, "the 3D radius with an
inlier floor")."""


CARRY_RADIUS_KEYPOINTS = ("all", "untracked")
"""``slam.carry_radius_keypoints``: which keypoints near the carried people the radius flags."""


def classes_near(
    carried: CarriedMask, t_frame_kf: np.ndarray, points: np.ndarray, radius: float
) -> np.ndarray:
    """``(N,)`` uint8: for each of a frame's keypoints, its camera-frame point ``points`` (N, 3)
    m (NaN without depth), the class of the nearest carried point within ``radius`` m (the
    carried points in the frame's camera by ``t_frame_kf``, 4 x 4 ``T_frame,kf``); 0 where none
    is that near or the keypoint has no depth."""
    out = np.zeros(len(points), np.uint8)
    valid = np.isfinite(points).all(axis=1)
    if len(carried.points) == 0 or not valid.any():
        return out
    p = carried.points @ t_frame_kf[:3, :3].T + t_frame_kf[:3, 3]
    # A tree made for one query (built every frame): split at the sliding midpoint, not the
    # median, with larger leaves, about a third less CPU than scipy's defaults; the same
    # nearest point (up to exact ties in distance).
    tree = cKDTree(p, leafsize=32, balanced_tree=False, compact_nodes=False)
    dist, idx = tree.query(points[valid], distance_upper_bound=radius)
    hit = np.isfinite(dist)
    cls = np.zeros(int(valid.sum()), np.uint8)
    cls[hit] = carried.classes[idx[hit]]
    out[valid] = cls
    return out


def people_motion(
    carried: CarriedMask, pose_wc: np.ndarray, previous: tuple[np.ndarray, float] | None
) -> tuple[np.ndarray, float]:
    """Set ``carried.velocity``: each of its people (connected regions of at least
    :data:`MIN_PERSON_POINTS` grid points) moves as its 3D centroid did since the nearest
    centroid of ``previous`` (``(P, 3)`` map-frame centroids of the mask before, its stamp s),
    within :data:`MAX_PERSON_SPEED` times the time between them and capped at that speed; the
    others stand still. ``pose_wc`` (4, 4): the keyframe's camera-to-world pose. Returns this
    mask's ``(B, 3)`` centroids and stamp, the ``previous`` of the next."""
    velocity = np.zeros_like(carried.points)
    assert carried.region is not None
    ids, counts = np.unique(carried.region, return_counts=True)
    ids = ids[counts >= MIN_PERSON_POINTS]
    world = carried.points @ pose_wc[:3, :3].T + pose_wc[:3, 3]
    centroids = np.array([world[carried.region == i].mean(axis=0) for i in ids]).reshape(-1, 3)
    dt = carried.stamp - previous[1] if previous is not None else 0.0
    if previous is not None and dt > 0 and len(previous[0]):
        for i, c in zip(ids, centroids, strict=True):
            shift = c - previous[0]
            j = int(np.argmin(np.linalg.norm(shift, axis=1)))
            if np.linalg.norm(shift[j]) <= MAX_PERSON_SPEED * dt:
                v = shift[j] / dt
                v *= min(1.0, MAX_PERSON_SPEED / max(float(np.linalg.norm(v)), 1e-9))
                velocity[carried.region == i] = pose_wc[:3, :3].T @ v  # in the keyframe's frame
    carried.velocity = velocity
    return centroids, carried.stamp


def fill_depth(labels: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """``depth`` (H, W) m with its holes inside the labelled pixels of ``labels`` (H, W) filled:
    each connected labelled region's holes take the median of its measured depths, a region
    measured nowhere (a person closer than the sensor's range) the frame's nearest measured
    depth (1st percentile)."""
    valid = depth > 0
    holes = (labels > 0) & ~valid
    if not holes.any():
        return depth
    out = depth.astype(np.float32, copy=True)
    near = float(np.percentile(depth[valid], 1)) if valid.any() else 0.0
    _, comp = cv2.connectedComponents((labels > 0).astype(np.uint8), connectivity=8)
    for c in np.unique(comp[holes]):
        region = comp == c
        measured = depth[region & valid]
        out[region & holes] = float(np.median(measured)) if len(measured) else near
    return out


def mark_dynamic_points(slam_map: SlamMap, kf_id: int, region: np.ndarray) -> int:
    """Mark bad the map points that keyframe ``kf_id`` observes through a keypoint inside
    ``region`` ((H, W) bool dynamic pixels of its mask), and flag those keypoints dynamic;
    returns how many good points it marked."""
    kf = slam_map.keyframes[kf_id]
    inside = values_at(region, kf.features.xy)
    kf.dynamic = kf.dynamic | inside
    ids = kf.point_ids[inside & (kf.point_ids >= 0)]
    bad = slam_map.points.bad.view
    ids = ids[~bad[ids]]
    bad[ids] = True
    return len(ids)


def mark_matched(slam_map: SlamMap, region: np.ndarray, xy: np.ndarray, matched: np.ndarray) -> int:
    """Mark bad the map points a frame's keypoints at ``xy`` (N, 2) inside ``region`` ((H, W)
    bool dynamic pixels of the frame's own mask) were matched to (``matched`` (N,), -1 none);
    returns how many good points it marked."""
    ids = np.unique(matched[values_at(region, xy) & (matched >= 0)])
    bad = slam_map.points.bad.view
    ids = ids[~bad[ids]]
    bad[ids] = True
    return len(ids)


def frame_mask(
    slam_map: SlamMap, got: Delivered, region: np.ndarray | None, k: np.ndarray
) -> tuple[CarriedMask, int]:
    """A tracked frame's own mask (``slam.mask_max_age_s``; ``got.anchor`` set): the map points
    the frame was matched to inside its dynamic ``region`` ((H, W) bool, None: none) marked bad
    (:func:`mark_matched`), and the mask to carry from the frame's pose on its reference keyframe
    (``k`` (3, 3) the camera matrix); returns it and how many points it marked. Unlike a
    keyframe's, it corrects no past."""
    assert got.labels is not None and got.xy is not None and got.matched is not None
    marked = mark_matched(slam_map, region, got.xy, got.matched) if region is not None else 0
    stamp = got.frame.stamp
    return CarriedMask.of(-1, got.labels, got.frame.depth, k, stamp, got.anchor), marked


MASK_MAX_AGE_S: float | None = None
"""``slam.mask_max_age_s``'s default (off: only keyframes are segmented; at 1.0 s dropped by its
pre-registered rule, docs/results/slam.md, "a mask for a frame when the carried one is
stale")."""


MASK_REFINES_PAST = ("none", "points", "mask")
"""``slam.mask_refines_past``: what a late mask corrects in the past
(:meth:`~.frame_loop.FrameLoop.refine_past`)."""

MASK_REFINES_PAST_DEFAULT = "mask"
"""``slam.mask_refines_past``'s default (docs/results/slam.md, "a late mask corrects the
past")."""

MASK_MARKS_PROJECTED = False
"""``slam.mask_marks_projected``'s default (the same entry: off since its confirmation on unseen
renders, where 2 of 9 repeats ended at 0.29 and 0.78 m)."""

CARRY_TO_KEYFRAMES = ("none", "newer", "since_previous")
"""``slam.carry_to_keyframes``: which other keyframes a delivered mask is carried to
(:func:`carry_targets`)."""


def carry_refused(reach: str, segment: str) -> str | None:
    """One line when ``slam.carry_to_keyframes`` asks for carried masks (``reach``;
    ``velocity``: ``slam.carry_velocity=true``) with a ``segment`` schedule other than ``thread``
    (the only one with delivered masks), else None."""
    if reach != "none" and segment != "thread":
        key = "carry_velocity=true" if reach == "velocity" else f"carry_to_keyframes={reach}"
        return f"slam.{key} needs segment=thread (got segment={segment})"
    return None


def carry_targets(slam_map: SlamMap, kf_id: int, previous: int | None, reach: str) -> list[int]:
    """The good keyframes, other than ``kf_id``, whose points keyframe ``kf_id``'s delivered
    mask also marks: ``none``: no other; ``newer``: every keyframe made after it;
    ``since_previous``: also those made after ``previous`` (the keyframe of the mask delivered
    before, None: from the first keyframe on), the ones the thread skipped before it."""
    if reach not in CARRY_TO_KEYFRAMES:
        raise ValueError(f"carry_to_keyframes: expected one of {CARRY_TO_KEYFRAMES}, got {reach!r}")
    if reach == "none":
        return []
    first = kf_id + 1 if reach == "newer" else (0 if previous is None else previous + 1)
    return [kf.id for kf in slam_map.keyframes[first:] if not kf.bad and kf.id != kf_id]


def mark_carried(
    slam_map: SlamMap,
    carried: CarriedMask,
    targets: list[int],
    region_of: Callable[[np.ndarray], np.ndarray | None],
) -> int:
    """Carry ``carried`` (a delivered keyframe mask) to each keyframe in ``targets`` by their
    map poses now (:meth:`CarriedMask.labels_at`), and mark bad the map points each observes
    inside ``region_of(labels)`` ((H, W) bool dynamic pixels of the carried ``(H, W)`` labels,
    None: none), as its own mask would (:func:`mark_dynamic_points`); returns how many good
    points were marked."""
    marked = 0
    pose_kf = carried.source_pose(slam_map)
    for target in targets:
        labels = carried.labels_at(invert(slam_map.pose_wc(target)) @ pose_kf)
        region = region_of(labels)
        if region is not None and region.any():
            marked += mark_dynamic_points(slam_map, target, region)
    return marked

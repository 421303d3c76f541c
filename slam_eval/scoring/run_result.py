"""What a harness run produced, the record the scoring reads (:class:`RunResult`): written by
:class:`~..systems.harness.SlamPipeline`, turned into files by :mod:`.report` and
:mod:`.repeats`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from uss_slam.core.tum_io import Trajectory

from ..products.octomap import SemanticOctoMap
from ..products.semantic_map import PointCloud


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
    cpu_ms: dict[str, float]
    wall_time_s: float
    cloud: PointCloud
    log: list[FrameLog] = field(repr=False, default_factory=list)
    segment: str = "every_frame"
    """The segmentation schedule (:data:`~..systems.harness.SEGMENT_SCHEDULES`)."""
    segmented_frames: int = 0
    """Frames for which the segmenter returned labels."""
    segmentation_ms: dict[str, float] = field(default_factory=dict)
    """``{"wall": ms, "cpu": ms}`` mean per segmented frame (empty when nothing was segmented)."""
    segmentation_thread: str = "prefetch"
    """Where the segmenter ran: ``"prefetch"`` (worker threads, concurrently with ORB
    extraction), ``"main"`` (keyframes schedule, or ``parallel`` off) or ``"semantic"`` (the
    semantic thread of ``segment=thread``)."""
    semantic_thread: dict[str, float | int | str] | None = None
    """With ``segment=thread``: its ``clock`` (camera | wall), keyframes ``requested`` /
    ``skipped``, masks ``delivered``, ``mean_delay_s`` (request to delivery, camera time),
    ``mean_segment_s`` (wall clock: time in the segmenter) and map ``points_marked`` bad."""
    local_ba: dict[str, float | int | str] | None = None
    """Local mapping totals (:meth:`~..mapping.local_mapping.LocalMappingStats.as_dict`) with the
    ``depth_noise`` k its stereo factors model and ``depth_noise_from`` (where it came from);
    None when off."""
    rolling_shutter: dict[str, float | int | str] = field(default_factory=dict)
    """The readout the tracker corrected for (``readout`` s, 0 = none), ``readout_from`` (where
    it came from) and ``frames_corrected``."""
    loop_closing: bool = False
    loop_closures: list[dict[str, float | int]] = field(default_factory=list)
    """One entry per closed loop (:class:`~..mapping.loop_closing.LoopClosure`)."""
    loop_candidates_rejected: int = 0
    """Consistent loop candidates that failed the geometric verification."""
    octomap: SemanticOctoMap | None = None
    """The semantic OctoMap (``slam.map.octomap=true``), else None."""

    @property
    def tracked_fraction(self) -> float:
        return self.tracked / max(self.frames, 1)

    @property
    def fps(self) -> float:
        return self.frames / self.wall_time_s if self.wall_time_s > 0 else 0.0

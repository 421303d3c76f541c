"""What every dynamic-keypoint filter shares: the per-frame context it reads
(:class:`FilterContext`), what it returns (:class:`FilterOutput`), the base class
(:class:`DynamicFilter`) and pixel sampling (:func:`values_at`).

Every filter returns a :class:`FilterOutput`: which keypoints it judges dynamic, optionally the
dynamic pixel region (kept out of the semantic map), and how many keypoints it could judge.
Every filter declares its ``stage`` (:data:`STAGES`): ``"pre"`` filters run before tracking (they
need no pose); ``"post"`` filters run once the frame's pose is known, and the pose is then
re-refined without what they flagged. The order and the bookkeeping are :mod:`.chain`'s.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np

from ..frontend.orb import Features, OrbExtractor
from ..map.slam_map import SlamMap
from ..sequence import Frame

STAGES = ("pre", "post")
"""When a filter runs: before tracking (``pre``) or once the frame's pose is known (``post``)."""


@dataclass
class FilterContext:
    """What a filter may look at for the current frame.

    ``labels`` (H, W) uint8 class ids or None; ``pose_wc`` (4, 4) the current pose estimate
    (post-pose filters only); ``matched`` (N,) map point per keypoint (-1 none; post only);
    ``flags`` keypoint flags of the filters that ran before, by name; ``motion_flags`` the union
    of the flags of motion filters (flow, geometry) so far. ``map`` is the run's shared map
    (keyframes and map points; filters read it, never change it).
    """

    frame: Frame
    features: Features
    labels: np.ndarray | None
    extractor: OrbExtractor
    map: SlamMap
    previous: Frame | None = None
    pose_wc: np.ndarray | None = None
    matched: np.ndarray | None = None
    flags: dict[str, np.ndarray] = field(default_factory=dict)
    motion_flags: np.ndarray | None = None


@dataclass
class FilterOutput:
    """``dynamic`` (N,) bool; ``region`` (H, W) bool dynamic pixels or None; ``checked`` how many
    keypoints the filter could judge (e.g. the flow filter needs depth and a previous frame)."""

    dynamic: np.ndarray
    region: np.ndarray | None = None
    checked: int = 0


class DynamicFilter(ABC):
    """Base of the filters. A subclass sets ``name`` and ``stage`` (one of :data:`STAGES`:
    whether it needs the current pose; a filter without one is refused when it is built)."""

    name: str = "filter"
    stage: ClassVar[Literal["pre", "post"]]
    needs_labels: bool = False
    motion: bool = False
    """Its flags come from observed motion (the object rule counts them)."""
    masks_input: bool = False
    """It finds its dynamic pixels in the frame alone (:meth:`input_region`), so a system that
    takes no keypoint flags can be fed the frame with those pixels blanked (ORB-SLAM3)."""

    @abstractmethod
    def __call__(self, ctx: FilterContext) -> FilterOutput: ...

    def input_region(self, frame: Frame, labels: np.ndarray | None) -> np.ndarray | None:
        """``(H, W)`` bool dynamic pixels of ``frame`` found from its images and ``labels``
        alone (no keypoints, pose or map), for a filter with ``masks_input``; None for the
        others (the default)."""
        return None

    def input_settings(self) -> dict[str, Any]:
        """What shapes :meth:`input_region` (its parameters, for a report); {} by default."""
        return {}

    def idle_reason(self) -> str | None:
        """Why this filter, as configured, can flag no keypoint whatever the frames (``<its
        parameter> ...: ...``, for a warning), or None when it can flag some."""
        return None


def values_at(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Values of a (H, W) image at float pixel positions ``xy`` (nearest pixel, clamped)."""
    h, w = image.shape[:2]
    col = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
    return image[row, col]

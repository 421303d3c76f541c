"""The filters of one run in order: which run at which stage of a frame, what each flagged over
the run, and the dynamic region they leave out of the map products.

Per frame (:class:`FrameFilters`), in the order of ``filters=[...]``:

- ``pre`` stage, before tracking: the filters of stage ``"pre"``;
- ``post`` stage, once the frame has a pose: the filters of stage ``"post"``; the pose is then
  refined again without what they flagged (the caller's step);
- ``late`` stage, on a frame whose labels arrive only after tracking (``segment=keyframes``: the
  frame became a keyframe and was segmented then): every filter that needs labels, after the
  ``post`` ones.

A filter that needs labels runs at the ``pre`` / ``post`` stages only on a frame that has labels
when its filters start. Each filter sees the flags of those before it (``ctx.flags`` by name,
``ctx.motion_flags`` the union of the motion filters'). Counts per filter over the run
(:attr:`FilterChain.counts`): ``flagged`` the keypoints it judged dynamic, ``dropped`` those that
no earlier filter of the frame had flagged (so the ``dropped`` values add up to ``extracted -
kept``), ``checked`` the keypoints it could judge.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass

import numpy as np

from .base import DynamicFilter, FilterContext

COUNTS = ("flagged", "dropped", "checked")
"""The per-filter keypoint counts of a run (see the module docstring)."""

Clock = Callable[[str], AbstractContextManager[object]]
"""Times the block it wraps under a name (the harness's ``Timer``; ``filter.<name>`` here)."""


class FilterChain:
    """The filters of a run, in order, and their counts over the run."""

    def __init__(self, filters: Sequence[DynamicFilter], clock: Clock) -> None:
        self.filters = list(filters)
        self.names = [f.name for f in self.filters]
        self.counts: dict[str, dict[str, int]] = {
            key: dict.fromkeys(self.names, 0) for key in COUNTS
        }
        self.clock = clock

    def frame(self, ctx: FilterContext) -> FrameFilters:
        """The filters of one frame, over ``ctx`` (the frame's labels as they are now)."""
        ctx.motion_flags = np.zeros(len(ctx.features), bool)
        ready = [f for f in self.filters if ctx.labels is not None or not f.needs_labels]
        return FrameFilters(self, ctx, np.zeros(len(ctx.features), bool), [], ready)

    def apply(self, f: DynamicFilter, state: FrameFilters) -> None:
        """Run ``f`` on the frame of ``state``: time it, count it, add its flags and region."""
        ctx = state.ctx
        with self.clock(f"filter.{f.name}"):
            out = f(ctx)
        self.counts["flagged"][f.name] += int(out.dynamic.sum())
        self.counts["dropped"][f.name] += int((out.dynamic & ~state.dynamic).sum())
        self.counts["checked"][f.name] += out.checked
        state.dynamic = state.dynamic | out.dynamic
        ctx.flags[f.name] = out.dynamic
        if f.motion:
            ctx.motion_flags = ctx.motion_flags | out.dynamic
        if out.region is not None:
            state.regions.append(out.region)


@dataclass
class FrameFilters:
    """The filters' state on one frame: ``dynamic`` (N,) bool keypoints flagged so far,
    ``regions`` the (H, W) bool dynamic regions returned so far, ``ready`` the filters that can
    run on the frame's labels as they were when its filters started."""

    chain: FilterChain
    ctx: FilterContext
    dynamic: np.ndarray
    regions: list[np.ndarray]
    ready: list[DynamicFilter]

    def pre(self) -> np.ndarray:
        """The ``pre`` stage; returns :attr:`dynamic`."""
        for f in self.ready:
            if f.stage == "pre":
                self.chain.apply(f, self)
        return self.dynamic

    def after_pose(
        self, pose_wc: np.ndarray | None, matched: np.ndarray, late: bool = False
    ) -> bool:
        """The ``post`` stage, and the ``late`` one when ``late`` (labels arrived after
        tracking: ``ctx.labels`` holds them), on a frame tracked at ``pose_wc`` (4, 4) with
        ``matched`` (N,) map point per keypoint; nothing without a pose. True when they flagged
        a keypoint not flagged before (the pose leant on it)."""
        post = [f for f in self.ready if f.stage == "post"]
        later = [f for f in self.chain.filters if f.needs_labels] if late else []
        if pose_wc is None or not (post or later):
            return False
        self.ctx.pose_wc, self.ctx.matched = pose_wc, matched
        before = self.dynamic.copy()
        for f in post + later:
            self.chain.apply(f, self)
        return bool((self.dynamic & ~before).any())

    def region(self) -> np.ndarray | None:
        """``(H, W)`` bool union of the regions, or None when no filter returned one."""
        return np.logical_or.reduce(self.regions) if self.regions else None

"""The harness's frame loop: one shared map for tracking, the back end and the filters, and the
loop's steps giving the same run as :meth:`SlamPipeline.run`."""

from __future__ import annotations

import numpy as np

from uss_slam.slam_eval.filters.base import DynamicFilter, FilterContext, FilterOutput
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.frame_loop import Timer
from uss_slam.slam_eval.systems.harness import SlamPipeline


class MapSpy(DynamicFilter):
    """Records the map each frame's context holds; flags nothing."""

    name = "spy"
    stage = "post"

    def __init__(self) -> None:
        self.maps: list[object] = []

    def __call__(self, ctx: FilterContext) -> FilterOutput:
        self.maps.append(ctx.map)
        return FilterOutput(np.zeros(len(ctx.features), bool))


def test_the_harness_hands_one_map_to_tracking_the_back_end_and_the_filters(
    synthetic_sequence,
) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=12, size=(320, 240))
    spy = MapSpy()
    filters = [*build_filters(["semantic", "geometry"]), spy]

    def pipeline() -> SlamPipeline:
        sequence = TumSequence(path, load_labels=True)
        return SlamPipeline(sequence, LabelsSegmenter(), filters, local_ba=True,
                            loop_closing=True, progress=False, parallel=False)  # fmt: skip

    stepped = pipeline()
    loop = stepped._frame_loop(Timer())
    tracker, closer = loop.tracker, loop.closer
    assert loop.map is tracker.map
    assert closer is not None and closer.map is tracker.map
    assert closer.projection is tracker.projection and closer.sampler is tracker.sampler
    assert tracker.projection.map is tracker.map
    for frame in stepped.sequence.frames():
        loop.step(stepped._prepare(frame))
    assert spy.maps and all(m is tracker.map for m in spy.maps)
    # the steps, driven one by one, are the run
    result = pipeline().run()
    assert result.tracked == loop.counts["tracked"] == len(loop.log)
    assert result.keypoints["kept"] == loop.counts["kept"]
    assert result.keypoints["dropped"] == loop.chain.counts["dropped"]
    assert np.allclose(result.trajectory.positions, stepped._trajectory(loop).positions)

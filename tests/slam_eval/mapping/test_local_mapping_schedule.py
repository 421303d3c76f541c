"""The local mapper's schedule (``min_interval_s``): ORB-SLAM2's queue of new keyframes on the
camera clock. The adjustment itself is replaced by a recorder; the map is a stand-in with the
keyframes' ``bad`` flags."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.mapping.local_mapping import LocalMapping, LocalMappingConfig


def _mapper(interval: float) -> tuple[LocalMapping, list[int], SimpleNamespace]:
    mapper = LocalMapping(LocalMappingConfig(min_interval_s=interval), adjuster=None)
    adjusted: list[int] = []
    mapper.process = lambda slam_map, kf: adjusted.append(kf)  # type: ignore[method-assign]
    slam_map = SimpleNamespace(keyframes={k: SimpleNamespace(bad=False) for k in range(10)})
    return mapper, adjusted, slam_map


def test_without_an_interval_every_keyframe_is_adjusted_at_once() -> None:
    mapper, adjusted, slam_map = _mapper(0.0)
    assert [mapper.keyframe(slam_map, k, 0.01 * k) for k in (1, 2, 3)] == [True] * 3
    assert not mapper.frame(slam_map, 0.05)
    assert adjusted == [1, 2, 3]
    assert mapper.stats.deferred == mapper.stats.skipped == 0


def test_a_keyframe_made_while_busy_waits_and_a_newer_one_replaces_it() -> None:
    mapper, adjusted, slam_map = _mapper(0.5)
    assert mapper.keyframe(slam_map, 1, 1.0)  # free: adjusted now, busy until 1.5 s
    assert not mapper.keyframe(slam_map, 2, 1.2)  # waits
    assert not mapper.frame(slam_map, 1.3)
    assert not mapper.keyframe(slam_map, 3, 1.4)  # replaces 2 (skipped)
    assert mapper.frame(slam_map, 1.5)  # busy time over: the newest waiting one
    assert adjusted == [1, 3]
    assert not mapper.frame(slam_map, 1.6)  # nothing waits
    assert mapper.keyframe(slam_map, 4, 2.0)  # free again at 2.0 s
    assert adjusted == [1, 3, 4]
    assert (mapper.stats.deferred, mapper.stats.skipped) == (2, 1)


def test_a_waiting_keyframe_culled_meanwhile_is_not_adjusted() -> None:
    mapper, adjusted, slam_map = _mapper(0.5)
    mapper.keyframe(slam_map, 1, 1.0)
    mapper.keyframe(slam_map, 2, 1.1)
    slam_map.keyframes[2].bad = True
    assert not mapper.frame(slam_map, 1.6)
    assert adjusted == [1] and mapper.stats.skipped == 1 and mapper.waiting is None


def test_the_interval_is_checked() -> None:
    with pytest.raises(UssSlamError, match="min_interval_s"):
        LocalMappingConfig(min_interval_s=-1.0)

"""ORB-SLAM2's ``ORBmatcher`` and the pose hypotheses drawn from its matches, shared by tracking
and loop closing: descriptor matching in a radius (:mod:`.descriptor`), matching by projection
(:mod:`.projection`, with its :class:`~.projection.MatchThresholds`), matching to a keyframe's
map points (:mod:`.keyframe`) and PnP sampling (:mod:`.sampling`, with its
:class:`~.sampling.SamplingSettings`). Reads the shared map (:mod:`..map`); the pose refinement
it ends with is :mod:`..optim`.
"""

from dataclasses import fields
from typing import Any, TypeVar

Settings = TypeVar("Settings")


def settings_of(cls: type[Settings], source: Any) -> Settings:
    """The settings dataclass ``cls`` (:class:`~.projection.MatchThresholds`,
    :class:`~.sampling.SamplingSettings`) with the values of the same-named attributes of
    ``source`` (the tracker's config)."""
    return cls(**{f.name: getattr(source, f.name) for f in fields(cls)})  # type: ignore[arg-type]

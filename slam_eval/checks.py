"""The range checks of the SLAM settings' dataclasses (tracking, local mapping, loop closing).

Messages start with the field name: ``uss-slam`` prefixes the config section
(``slam.tracking.ratio must be in (0, 1], got 2``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import fields
from typing import Any


def check_numbers(
    config: Any,
    *,
    at_least_one: Iterable[str] = (),
    positive: Iterable[str] = (),
    unit: Iterable[str] = (),
) -> None:
    """Raise :class:`ValueError` unless every number field of the dataclass ``config`` is finite
    and >= 0 (true / false, strings and None are no numbers here), the fields ``at_least_one`` are
    >= 1, the fields ``positive`` > 0 and the fields ``unit`` in (0, 1]; checked in that order."""
    for item in fields(config):
        value = getattr(config, item.name)
        if value is None or isinstance(value, (bool, str)):  # None: an optional setting unset
            continue
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{item.name} must be a finite number >= 0, got {value}")
    for name in at_least_one:
        if getattr(config, name) < 1:
            raise ValueError(f"{name} must be >= 1, got {getattr(config, name)}")
    for name in positive:
        if getattr(config, name) <= 0:
            raise ValueError(f"{name} must be > 0, got {getattr(config, name)}")
    for name in unit:
        if not 0 < getattr(config, name) <= 1:
            raise ValueError(f"{name} must be in (0, 1], got {getattr(config, name)}")

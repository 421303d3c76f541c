"""Checks of ``uss-experiments``' values that the schema (:mod:`.schema`) cannot express: a
sequence of the data kind, the keys and values of the user's own mappings (``grid.loss``,
``grid.batchnorm``, ``grid.method_overrides``); each fails with the one-line error that names
the key. Types, ranges, choices and repeats of the other keys are the schema's."""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from uss_slam.core.errors import UssSlamError

LOSS_KEYS = ("lambda_seg_aux", "lambda_seg_main", "lambda_adv_aux", "lambda_adv_main")
"""The loss weights ``grid.loss`` may vary (``model.loss.<key>``; the adversarial ones
``model.method.<key>``)."""


def choose(key: str, value: Any, accepted: Iterable[str]) -> str:
    """``value`` if it is one of ``accepted``; else the one-line error naming ``key``."""
    accepted = tuple(accepted)
    if str(value) not in accepted:
        raise UssSlamError(f"{key}: unknown value {value!r}; accepted: {', '.join(accepted)}")
    return str(value)


def unique(key: str, values: Sequence[Any]) -> None:
    seen = [v for k, v in enumerate(values) if v in values[:k]]
    if seen:
        raise UssSlamError(f"{key}: {seen[0]!r} is listed twice")


def non_empty_list(key: str, values: Any) -> list[Any]:
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence) or not values:
        raise UssSlamError(f"{key}: expected a non-empty list, got {values!r}")
    return list(values)


def number(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UssSlamError(f"{key}: expected a number, got {value!r}")
    return float(value)


def given(values: Mapping[str, Any] | None) -> dict[str, Any]:
    """The entries of a mapping of options that are set (null = not given)."""
    return {k: v for k, v in (values or {}).items() if v is not None}


def check_sequences(sequences: Any, accepted: Sequence[str]) -> list[str]:
    """``sequences`` (the schema's: known names, each once) of the data kind: ``accepted``."""
    names = [str(s) for s in sequences]
    for s in names:
        choose("sequences", s, accepted)
    return names


def source_val_stride(cfg: Mapping[str, Any]) -> int | None:
    """``segeval.source_val_stride`` (T0's in-domain column: every n-th source validation
    image); None = not scored. Its type and range are the schema's."""
    stride = (cfg.get("segeval") or {}).get("source_val_stride")
    return None if stride is None else int(stride)


def loss_combinations(loss: Mapping[str, Any] | None) -> list[tuple[tuple[str, float], ...]]:
    """Every combination of the loss weights given as lists (``{key: [v1, v2]}``; null = not
    varied), in order."""
    loss = given(loss)
    if not loss:
        return [()]
    keys = list(loss)
    for key in keys:
        choose("grid.loss", key, LOSS_KEYS)
    values = []
    for key in keys:
        listed = loss[key]
        listed = [listed] if isinstance(listed, (int, float)) else listed
        items = non_empty_list(f"grid.loss.{key}", listed)
        nums = [number(f"grid.loss.{key}", v) for v in items]
        unique(f"grid.loss.{key}", nums)
        values.append(nums)
    return [tuple(zip(keys, combo, strict=True)) for combo in itertools.product(*values)]

"""Bad values of every key of a schema, generated from its declarations (types, ranges,
choices, the duplicate policy): what a test matrix feeds each script so that a new key enters
it without a list to edit (``tests/test_cli_matrix.py``).

For each leaf key: a value of the wrong type, each bound crossed (``min`` - 1, ``gt`` itself,
``max`` + 1, ``lt`` itself), an unknown choice, ``null`` where the key takes none, an empty
list where one is refused, a name listed twice where the list's policy refuses repeats; for
each section, an unknown key. Keys the schema leaves open (``Any`` without metadata, the
user's own mappings) get none.
"""

from __future__ import annotations

import dataclasses
import enum
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

from omegaconf import MISSING

from .checking import _join
from .fields import _MAPPINGS, _SEQUENCES, _hints, _optional, repeats_refused

KINDS = ("type", "range", "empty", "duplicate", "unknown")
"""What a generated value is wrong in."""
UNKNOWN_KEY = "no_such_key"
"""The name of the unknown key added to each section."""


@dataclass(frozen=True)
class BadValue:
    """``value`` at ``key`` (a full dotted key) is wrong in ``kind`` (:data:`KINDS`)."""

    key: str
    kind: str
    value: Any

    @property
    def id(self) -> str:
        return f"{self.key}={self.value!r}"


def bad_values(schema: type, key: str = "") -> Iterator[BadValue]:
    """Every :class:`BadValue` of the dataclass ``schema`` (``key``: its dotted path)."""
    hints = _hints(schema)
    yield BadValue(_join(key, UNKNOWN_KEY), "unknown", 1)
    for f in dataclasses.fields(schema):
        required = f.default is MISSING and f.default_factory is dataclasses.MISSING
        yield from _of(hints[f.name], dict(f.metadata), _join(key, f.name), required)


def _of(tp: Any, metadata: dict[str, Any], where: str, required: bool) -> Iterator[BadValue]:
    inner, nullable = _optional(tp)
    nullable = nullable or None in metadata.get("choices", ())
    if dataclasses.is_dataclass(inner):
        yield from bad_values(inner, where)  # type: ignore[arg-type]
        return
    if inner is Any and not metadata:
        return  # open: judged by whoever reads it
    if not nullable and not required:
        yield BadValue(where, "empty", None)
    if "choices" in metadata:
        yield BadValue(where, "range", "no_such_choice")
        return
    if metadata.get("text"):
        return  # any scalar is its text
    origin = typing.get_origin(inner)
    if origin in _SEQUENCES or inner in (list, tuple):
        yield from _of_list(inner, metadata, where)
        return
    if origin in _MAPPINGS or inner is dict:
        return
    yield from _of_scalar(inner, metadata, where)


def _of_scalar(tp: Any, metadata: dict[str, Any], where: str) -> Iterator[BadValue]:
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        yield BadValue(where, "range", "no_such_choice")
        return
    if typing.get_origin(tp) is Literal:
        yield BadValue(where, "range", "no_such_choice")
        return
    wrong = {int: "abc", float: "abc", bool: "maybe", str: [1, 2]}.get(tp)
    if wrong is None and tp is not Any:
        return
    if wrong is not None:
        yield BadValue(where, "type", wrong)
    for value in _crossed(tp, metadata):
        yield BadValue(where, "range", value)


def _crossed(tp: Any, metadata: dict[str, Any]) -> list[Any]:
    """A value just outside each bound of ``metadata``."""
    step = 1 if tp is int else 1.0 if tp is float else 1
    out = []
    if "min" in metadata:
        out.append(metadata["min"] - step)
    if "gt" in metadata:
        out.append(metadata["gt"])
    if "max" in metadata:
        out.append(metadata["max"] + step)
    if "lt" in metadata:
        out.append(metadata["lt"])
    return out


def _of_list(tp: Any, metadata: dict[str, Any], where: str) -> Iterator[BadValue]:
    args = [a for a in typing.get_args(tp) if a is not Ellipsis]
    element = args[0] if args else Any
    yield BadValue(where, "type", "abc")
    if metadata.get("nonempty"):
        yield BadValue(where, "empty", [])
    sample = _sample(element)
    if sample is not None and repeats_refused(element, metadata):
        yield BadValue(where, "duplicate", [sample, sample])
    inner, _ = _optional(element)
    for value in _crossed(inner, metadata):
        yield BadValue(where, "range", [value])


def _sample(element: Any) -> Any:
    """A valid item of a list of ``element`` (None where none can be made up)."""
    inner, _ = _optional(element)
    if isinstance(inner, type) and issubclass(inner, enum.Enum):
        return next(iter(inner)).name
    if typing.get_origin(inner) is Literal:
        return typing.get_args(inner)[0]
    return {str: "a", int: 1, float: 1.0}.get(inner)

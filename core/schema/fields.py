"""What a schema declares: :class:`SchemaError`, the range metadata of a field (:func:`ranged`,
or :class:`Range` inside ``typing.Annotated`` for a constructor parameter) and the text that
tells a person what a value must be (:func:`describe`)."""

from __future__ import annotations

import dataclasses
import enum
import functools
import re
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal, Union

from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf

from uss_slam.core.errors import UssSlamError
from uss_slam.core.ranges import MAX_THREADS, THREADS, Range, machine_threads  # noqa: F401

RANGE_KEYS = ("min", "max", "gt", "lt", "choices", "length", "text", "nonempty", "unique")
"""Field metadata that :func:`validate` checks after the types (``text``: a string field that
takes any scalar as its text, e.g. a run name given as a number; on a list field ``min``,
``max``, ``gt`` and ``lt`` bound each element, ``nonempty`` refuses an empty list,
``unique`` its duplicate policy: :func:`repeats_refused`)."""
NEEDS = "needs"
"""Field metadata: the boolean sibling field without which the field changes nothing
(:func:`~.checking.unused_settings` warns when it is set while that one is false)."""


_SCALARS: dict[Any, str] = {int: "an integer", float: "a number", bool: "true or false",
                            str: "a string"}  # fmt: skip
_PLURALS: dict[Any, str] = {int: "integers", float: "numbers", bool: "booleans", str: "strings"}
_SEQUENCES = (list, tuple, Sequence, typing.Sequence, typing.List, typing.Tuple)  # noqa: UP006
_MAPPINGS = (dict, Mapping, typing.Mapping, typing.Dict)  # noqa: UP006


class SchemaError(UssSlamError, ValueError):
    """A config value that does not fit its schema: ``<key>: expected <what>, got <value>``
    (or ``<key>: unknown key; expected one of ...``)."""

    def __init__(
        self, key: str, expected: str, got: Any = MISSING, *, unknown: bool = False, owner: str = ""
    ) -> None:
        self.key = key or "config"
        self._args = (expected, got, unknown, owner)
        expected = _SIBLING.sub(r"\1", expected)  # {ini_fast}: another key of the section
        self.expected = expected
        if unknown and not expected:
            message = f"{self.key}: unknown key; {owner or 'this section'} takes no parameters"
        elif unknown:
            message = f"{self.key}: unknown key; expected one of {expected}"
            if owner:
                message += f" (the parameters of {owner})"
        elif got is MISSING:
            message = f"{self.key}: expected {expected}"
        else:
            message = f"{self.key}: expected {expected}, got {_show(got)}"
        super().__init__(message)

    def as_flag(self) -> SchemaError:
        """The same error naming the command-line flag of its key (``frame_iou`` ->
        ``--frame-iou``), for a script whose options are checked against a schema."""
        expected, got, unknown, owner = self._args
        return SchemaError("--" + self.key.replace("_", "-"), expected, got, unknown=unknown,
                           owner=owner)  # fmt: skip

    def within(self, section: str) -> SchemaError:
        """The same error with ``section`` (a dotted config path) before its key: a settings
        object built from a section names the field, the caller knows the section."""
        expected, got, unknown, owner = self._args
        key = f"{section}.{self.key}" if section else self.key
        if section:  # a rule's other key, written {name}, gets the section too
            expected = _SIBLING.sub(lambda m: "{" + f"{section}.{m.group(1)}" + "}", expected)
        return SchemaError(key, expected, got, unknown=unknown, owner=owner)


_SIBLING = re.compile(r"\{([\w.]+)\}")
"""A key named inside a rule's ``expected`` text (``an integer <= {ini_fast}``): prefixed with
the section by :meth:`SchemaError.within`, shown without the braces."""


def _show(value: Any) -> str:
    if isinstance(value, enum.Enum):
        return repr(value.name)
    if isinstance(value, (DictConfig, ListConfig)):
        value = OmegaConf.to_container(value, resolve=False)
    return repr(value)


def ranged(
    default: Any = MISSING,
    *,
    default_factory: Callable[[], Any] | None = None,
    min: float | None = None,  # noqa: A002 (the metadata's own names)
    max: float | None = None,  # noqa: A002
    gt: float | None = None,
    lt: float | None = None,
    choices: Sequence[Any] | None = None,
    length: int | None = None,
    text: bool | None = None,
    nonempty: bool | None = None,
    unique: bool | None = None,
    needs: str | None = None,
) -> Any:
    """A dataclass field with range metadata: ``n: int = ranged(1, min=1)``; on a list field
    the bounds are each element's: ``seeds: list[int] = ranged(..., min=0, nonempty=True)``."""
    metadata = Range(min=min, max=max, gt=gt, lt=lt, choices=choices, length=length, text=text,
                     nonempty=nonempty, unique=unique).metadata  # fmt: skip
    if needs is not None:
        metadata[NEEDS] = needs
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def repeats_refused(element: Any, metadata: Mapping[str, Any]) -> bool:
    """The duplicate policy of a list, one rule for every schema: a list of names (strings,
    choices, Enums: stages, classes, folders, filters) refuses an item listed twice; a list of
    numbers is a vector (a mean, betas, a size) whose items may repeat. ``unique`` in the
    field's metadata overrides either way."""
    if "unique" in metadata:
        return bool(metadata["unique"])
    inner, _ = _optional(element)
    if inner is str or (isinstance(inner, type) and issubclass(inner, enum.Enum)):
        return True
    return typing.get_origin(inner) is Literal


# ---------------------------------------------------------------------------- type helpers


def _optional(tp: Any) -> tuple[Any, bool]:
    """``(inner type, whether null is allowed)``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if (origin is Union or origin is types.UnionType) and type(None) in args:
        rest = [a for a in args if a is not type(None)]
        return (rest[0] if len(rest) == 1 else Union[tuple(rest)]), True  # noqa: UP007
    return tp, tp is Any


def describe(tp: Any, metadata: Mapping[str, Any] | None = None) -> str:
    """What a value of type ``tp`` (with range ``metadata``) must be, for a person:
    ``Optional[int]`` with ``min=1`` -> "an integer >= 1 or null"."""
    metadata = metadata or {}
    inner, nullable = _optional(tp)
    if "choices" in metadata:
        text = "one of " + ", ".join(_choice(c) for c in metadata["choices"] if c is not None)
        nullable = nullable or None in metadata["choices"]
    else:
        text = _describe(inner)
        if inner is Any and any(k in metadata for k in ("min", "max", "gt", "lt")):
            text = "a number"  # e.g. a size given as one number or a list
        elif inner is Any and metadata.get("unique"):
            text = "a list"  # e.g. folders given as one or a list
        bounds = [f"{op} {metadata[k]}" for k, op in (("min", ">="), ("gt", ">"), ("max", "<="),
                                                       ("lt", "<")) if k in metadata]  # fmt: skip
        if bounds:
            text += " " + " and ".join(bounds)
        if "length" in metadata:
            text += f" of length {metadata['length']}"
        if metadata.get("unique") and text.startswith("a list"):
            text += ", each once"
        if metadata.get("nonempty") and text.startswith("a list"):
            text = "a non-empty list" + text.removeprefix("a list")
    return text + (" or null" if nullable and tp is not Any else "")


def _choice(value: Any) -> str:
    return value.name if isinstance(value, enum.Enum) else repr(value)


def _describe(tp: Any) -> str:
    if tp is Any:
        return "any value"
    if tp in _SCALARS:
        return _SCALARS[tp]
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return "one of " + ", ".join(m.name for m in tp)
    if dataclasses.is_dataclass(tp):
        return f"a mapping of {tp.__name__}'s keys"
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin is Union or origin is types.UnionType:
        return " or ".join(dict.fromkeys(_describe(a) for a in args))
    if origin in _SEQUENCES or tp in (list, tuple):
        inner = [a for a in args if a is not Ellipsis]
        if not inner or inner[0] is Any:
            return "a list"
        if isinstance(inner[0], type) and issubclass(inner[0], enum.Enum):
            return "a list of " + ", ".join(m.name for m in inner[0])
        return f"a list of {_PLURALS.get(inner[0]) or _describe(inner[0])}"
    if origin in _MAPPINGS or tp is dict:
        return "a mapping"
    return getattr(tp, "__name__", str(tp))


@functools.cache
def _hints(schema: type) -> dict[str, Any]:
    return typing.get_type_hints(schema)


def structured(schema: type) -> DictConfig:
    """The structured config of ``schema`` with every node writable (a frozen dataclass gives
    read-only nodes, which Hydra could not override; the types are still enforced)."""
    node = OmegaConf.structured(schema)

    def unlock(cfg: Any) -> None:
        if isinstance(cfg, DictConfig):
            OmegaConf.set_readonly(cfg, False)
            for name in cfg:
                unlock(cfg._get_node(name))

    unlock(node)
    return node

"""Typed config schemas: the one layer that checks the values of every command's config.

A schema is a dataclass: its annotations give the types (``int``, ``float``, ``bool``, ``str``,
Enums, ``Optional``, lists, nested dataclasses), OmegaConf enforces them, and value ranges are
field metadata (:func:`ranged`: ``min``, ``max``, ``gt``, ``lt``, ``choices``, ``length``).
Schemas are registered in Hydra's ConfigStore (:func:`register`) where a config composes them
in its defaults list, or applied to a composed config (:func:`validate`).

Objects built with ``_target_`` are checked against a schema derived from their target's
parameter annotations (:func:`target_schema`, :func:`check_targets`): what a config can express
(numbers, booleans, strings, ``null``, literals, lists of those) is judged; a parameter whose
annotation admits other objects is left to the target.

Every problem is a :class:`SchemaError`, one line ``<key>: expected <what>, got <value>``,
built from OmegaConf's exception attributes (``full_key``, ``value``, the schema's field type),
never from its message text.
"""

from __future__ import annotations

import dataclasses
import enum
import inspect
import math
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, Literal, Optional, Union

from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from omegaconf.errors import (
    ConfigAttributeError,
    ConfigKeyError,
    KeyValidationError,
    MissingMandatoryValue,
    OmegaConfBaseException,
    ValidationError,
)

from uss_slam.core.errors import UssSlamError

RANGE_KEYS = ("min", "max", "gt", "lt", "choices", "length", "text", "nonempty")
"""Field metadata that :func:`validate` checks after the types (``text``: a string field that
takes any scalar as its text, e.g. a run name given as a number; on a list field ``min``,
``max``, ``gt`` and ``lt`` bound each element, ``nonempty`` refuses an empty list)."""

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
) -> Any:
    """A dataclass field with range metadata: ``n: int = ranged(1, min=1)``; on a list field
    the bounds are each element's: ``seeds: list[int] = ranged(..., min=0, nonempty=True)``."""
    metadata = {k: v for k, v in (("min", min), ("max", max), ("gt", gt), ("lt", lt),
                                  ("choices", choices), ("length", length), ("text", text),
                                  ("nonempty", nonempty)) if v is not None}  # fmt: skip
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


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
        bounds = [f"{op} {metadata[k]}" for k, op in (("min", ">="), ("gt", ">"), ("max", "<="),
                                                       ("lt", "<")) if k in metadata]  # fmt: skip
        if bounds:
            text += " " + " and ".join(bounds)
        if "length" in metadata:
            text += f" of length {metadata['length']}"
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


# ------------------------------------------------------------------------------ validation


def validate(node: Any, schema: type, key: str = "") -> Any:
    """Check ``node`` (a mapping or DictConfig; ``key`` its dotted path in the config) against
    the dataclass ``schema`` and return the schema's object built from it.

    Types by OmegaConf's structured merge, then :data:`RANGE_KEYS` metadata and the values as
    written (a ``"3"`` where an integer is expected, ``1`` for a boolean, a non-finite number)
    by a walk over the schema. Raises :class:`SchemaError` naming the full key."""
    typed = check(node, schema, key)
    try:
        return OmegaConf.to_object(typed)
    except OmegaConfBaseException as error:  # a required value left ??? (MISSING)
        raise _schema_error(error, schema, key) from None


def check(node: Any, schema: type, key: str = "") -> DictConfig:
    """:func:`validate` without building the object (for schemas of ``_target_`` parameters,
    whose values are left ``???`` or set later): returns the typed config."""
    plain = _plain(node)
    if plain is None:
        plain = {}
    if not isinstance(plain, Mapping):
        raise SchemaError(key, _describe(schema), plain)
    try:
        typed = OmegaConf.merge(structured(schema), plain)
    except OmegaConfBaseException as error:
        if not error.full_key:  # a section of the wrong shape: the walk names it
            _walk(schema, plain, key)
        raise _schema_error(error, schema, key) from None
    _walk(schema, plain, key)
    assert isinstance(typed, DictConfig)
    return typed


def _plain(node: Any) -> Any:
    if isinstance(node, (DictConfig, ListConfig)):
        return OmegaConf.to_container(node, resolve=True, throw_on_missing=False)
    if isinstance(node, Mapping):
        return {name: _plain(value) for name, value in node.items()}
    if isinstance(node, (list, tuple)):
        return [_plain(value) for value in node]
    return node


def _join(key: str, name: str | int) -> str:
    if isinstance(name, int):
        return f"{key}[{name}]"
    return f"{key}.{name}" if key else str(name)


def _schema_error(error: OmegaConfBaseException, schema: type, key: str) -> SchemaError:
    """A :class:`SchemaError` from OmegaConf's exception attributes: its ``full_key`` (relative
    to ``schema``), ``value``, and the field type found at that key."""
    relative = str(error.full_key or "")
    where = _prefix(key, relative)
    tp, metadata, parent = _type_at(schema, relative)
    if isinstance(error, ConfigKeyError) and dataclasses.is_dataclass(parent):
        names = ", ".join(f.name for f in dataclasses.fields(parent))
        return SchemaError(where, names, unknown=True)
    expected = describe(tp, metadata) if tp is not None else "a valid value"
    if isinstance(error, MissingMandatoryValue):
        return SchemaError(where, f"{expected} (no value was given)")
    if isinstance(error, ValidationError):
        return SchemaError(where, expected, error.value)
    return SchemaError(where, expected)


def _prefix(key: str, relative: str) -> str:
    if not relative:
        return key
    if not key:
        return relative
    return f"{key}{relative}" if relative.startswith("[") else f"{key}.{relative}"


def _path(relative: str) -> list[str | int]:
    """``"a.b[2].c"`` -> ``["a", "b", 2, "c"]``."""
    parts: list[str | int] = []
    for piece in relative.replace("]", "").split("."):
        name, *indices = piece.split("[")
        if name:
            parts.append(name)
        parts.extend(int(i) for i in indices if i.lstrip("-").isdigit())
    return parts


def _type_at(schema: type, relative: str) -> tuple[Any, dict[str, Any], Any]:
    """``(field type, its metadata, the dataclass or list type holding it)`` at ``relative``
    in ``schema``; ``(None, {}, None)`` where the path leaves the schema."""
    tp: Any = schema
    metadata: dict[str, Any] = {}
    parent: Any = None
    for part in _path(relative):
        inner, _ = _optional(tp)
        parent = inner
        if isinstance(part, int):
            args = [a for a in typing.get_args(inner) if a is not Ellipsis]
            bounds = {k: v for k, v in metadata.items() if k in ("min", "max", "gt", "lt")}
            tp, metadata = (args[0] if args else Any), bounds
        elif dataclasses.is_dataclass(inner):
            found = {f.name: f for f in dataclasses.fields(inner)}.get(part)
            if found is None:
                return None, {}, inner
            tp, metadata = _hints(inner)[part], dict(found.metadata)
        else:
            args = typing.get_args(inner)
            tp, metadata = (args[1] if len(args) == 2 else Any), {}
    return tp, metadata, parent


def _hints(schema: type) -> dict[str, Any]:
    return typing.get_type_hints(schema)


def _walk(schema: type, values: Mapping[str, Any], key: str) -> None:
    """Range metadata and the values as written, field by field (``values``: plain, resolved)."""
    hints = _hints(schema)
    for f in dataclasses.fields(schema):
        if f.name not in values:
            continue
        _check_value(values[f.name], hints[f.name], dict(f.metadata), _join(key, f.name))


def _check_value(value: Any, tp: Any, metadata: dict[str, Any], where: str) -> None:
    if value == "???" or value is MISSING:
        return  # left to whoever requires it
    inner, nullable = _optional(tp)
    if value is None:
        if nullable or None in metadata.get("choices", ()):
            return
        raise SchemaError(where, describe(tp, metadata), value)
    if "choices" in metadata:
        if not any(type(value) is type(c) and value == c for c in metadata["choices"]):
            raise SchemaError(where, describe(tp, metadata), value)
        return
    if dataclasses.is_dataclass(inner):
        if not isinstance(value, Mapping):
            raise SchemaError(where, describe(tp, metadata), value)
        _walk(inner, value, where)
        return
    if metadata.get("text") and not isinstance(value, (Mapping, list, tuple)):
        return  # a name: a number given on the command line is taken as its text
    if not _written_as(inner, value):
        if inner is float and isinstance(value, float):
            raise SchemaError(where, "a finite number", value)
        raise SchemaError(where, describe(tp, metadata), value)
    origin, args = typing.get_origin(inner), typing.get_args(inner)
    if origin in _SEQUENCES and isinstance(value, (list, tuple)):
        if ("length" in metadata and len(value) != metadata["length"]) or (
            metadata.get("nonempty") and not value
        ):
            raise SchemaError(where, describe(tp, metadata), value)
        element = args[0] if args else Any
        each = {k: v for k, v in metadata.items() if k in ("min", "max", "gt", "lt", "text")}
        for i, item in enumerate(value):
            _check_value(item, element, each, _join(where, i))
        return
    if origin in _MAPPINGS and isinstance(value, Mapping) and len(args) == 2:
        for name, item in value.items():
            _check_value(item, args[1], {}, _join(where, str(name)))
        return
    _check_range(value, tp, metadata, where)


def _written_as(tp: Any, value: Any) -> bool:
    """Whether ``value`` is written as a ``tp`` (OmegaConf converts ``"3"`` to 3 and 1 to
    true; a target built from the config would get the string or the integer)."""
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is float:
        return (
            isinstance(value, (int, float))
            and not isinstance(value, bool)
            and math.isfinite(float(value))
        )
    if tp is str:
        return isinstance(value, str)
    origin = typing.get_origin(tp)
    if origin is Union or origin is types.UnionType:
        return any(_written_as(a, value) for a in typing.get_args(tp))
    if origin in _SEQUENCES:
        return isinstance(value, (list, tuple))
    if origin in _MAPPINGS:
        return isinstance(value, Mapping)
    return True  # Enums, Any: OmegaConf's merge judged them


def _check_range(value: Any, tp: Any, metadata: dict[str, Any], where: str) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return
    low, high = metadata.get("min"), metadata.get("max")
    above, below = metadata.get("gt"), metadata.get("lt")
    if (
        (low is not None and not value >= low)
        or (high is not None and not value <= high)
        or (above is not None and not value > above)
        or (below is not None and not value < below)
    ):
        raise SchemaError(where, describe(tp, metadata), value)


# ---------------------------------------------------------------- errors while composing


def omegaconf_error_line(error: OmegaConfBaseException) -> str:
    """One line ``<key>: expected ..., got ...`` for an OmegaConf error raised while a config
    is composed or read (a typed structured config, a struct node), from the exception's
    attributes: ``full_key``, ``value``, the dataclass or node the key belongs to
    (``object_type``, ``parent_node``, ``child_node``). Where those say nothing about what was
    expected (an interpolation that cannot be resolved, say), the line is the key and the first
    line of OmegaConf's message."""
    key = str(error.full_key or error.key or "")
    if isinstance(error, (ConfigKeyError, ConfigAttributeError)):
        names = _known_keys(error, key)
        if names is not None:
            return str(SchemaError(key, ", ".join(names), unknown=True))
    if isinstance(error, MissingMandatoryValue):
        return f"{key}: expected a value (it is required and none was given)"
    if isinstance(error, ValidationError) and not isinstance(error, KeyValidationError):
        expected = _expected_of(error)
        if expected is not None:
            return str(SchemaError(key, expected, error.value))
    text = str(error.msg or error).strip().splitlines()
    message = " ".join(text[0].split()) if text else type(error).__name__
    return f"{key}: {message}" if key and key not in message else message


def _known_keys(error: OmegaConfBaseException, key: str) -> list[str] | None:
    """The keys the node of ``error`` accepts: the fields of its dataclass, else the keys of
    its struct node (without ``_target_``-like and, at the root, Hydra's own keys)."""
    if dataclasses.is_dataclass(error.object_type):
        return [f.name for f in dataclasses.fields(error.object_type)]
    parent = error.parent_node
    if isinstance(parent, DictConfig):
        root = "." not in key
        return [
            str(k) for k in parent if not str(k).startswith("_") and not (root and k == "hydra")
        ]
    return None


_NODE_TYPES = {
    "IntegerNode": int, "FloatNode": float, "BooleanNode": bool, "StringNode": str,
}  # fmt: skip


def _expected_of(error: OmegaConfBaseException) -> str | None:
    """What the key of a ``ValidationError`` takes: its dataclass field's type, else the type
    of the value node it was assigned to."""
    owner, name = error.object_type, error.key
    if dataclasses.is_dataclass(owner) and isinstance(name, str):
        found = {f.name: f for f in dataclasses.fields(owner)}.get(name)
        if found is not None:
            return describe(_hints(owner)[name], dict(found.metadata))
    node = error.child_node
    if node is not None:
        kind = _NODE_TYPES.get(type(node).__name__)
        if kind is not None:
            return describe(Optional[kind] if node._is_optional() else kind)  # noqa: UP045
        enum_type = getattr(node, "enum_type", None)
        if enum_type is not None:
            return describe(enum_type)
    if isinstance(error.ref_type, type) and issubclass(error.ref_type, enum.Enum):
        return describe(error.ref_type)
    return None


# ------------------------------------------------------------------------- the ConfigStore


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


def register(group: str, name: str, schema: type) -> None:
    """Store ``schema`` in Hydra's ConfigStore as ``<group>/<name>`` (for a defaults list:
    ``- /<group>/<name>@<package>``); idempotent."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(group=group, name=name, node=structured(schema))


# ---------------------------------------------------------- schemas of _target_ parameters


def _config_type(annotation: Any, opaque: tuple[type, ...]) -> tuple[Any, dict[str, Any]]:
    """The OmegaConf type (and range metadata) of a parameter annotation: what a config value
    can be checked against; ``Any`` where the annotation admits objects a config cannot hold
    or judge. ``opaque``: classes that are never config values (dropped from unions)."""
    if annotation in _SCALARS:
        return annotation, {}
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Literal:
        return Any, {"choices": tuple(args)}
    if origin is Union or origin is types.UnionType:
        members = [a for a in args if a is not type(None) and a not in opaque]
        nullable = type(None) in args
        if members and all(typing.get_origin(a) is Literal for a in members):
            choices = tuple(c for a in members for c in typing.get_args(a))
            return Any, {"choices": choices + ((None,) if nullable else ())}
        mapped = [_config_type(a, opaque) for a in members]
        if not members or any(t is Any or m for t, m in mapped):
            return Any, {}
        kinds = tuple(dict.fromkeys(t for t, _ in mapped))
        if len(kinds) > 1 and not all(k in _SCALARS for k in kinds):
            return Any, {}  # a list or a scalar: OmegaConf has no such union
        tp = kinds[0] if len(kinds) == 1 else Union[kinds]  # noqa: UP007
        return (Optional[tp] if nullable else tp), {}  # noqa: UP045
    if origin in _SEQUENCES or annotation in (list, tuple):
        items = [a for a in args if a is not Ellipsis]
        metadata = {}
        if origin is tuple and args and Ellipsis not in args:
            metadata["length"] = len(args)
        element: Any = Any
        if items and len(set(items)) == 1:
            element, extra = _config_type(items[0], opaque)
            if extra or element not in _SCALARS:
                element = Any
        return list[element], metadata
    if origin in _MAPPINGS or annotation is dict:
        return dict[str, Any], {}
    return Any, {}


def target_schema(target: str | Callable[..., Any], opaque: Iterable[type] = ()) -> type | None:
    """A schema of the parameters of ``target`` (a ``_target_`` path or the callable), from its
    annotations; None when it cannot be imported or its annotations cannot be read (then the
    target reports its own problem when it is built). A target taking ``**kwargs`` gives a
    schema of its named parameters only (:func:`check_targets` leaves the other keys)."""
    opaque = tuple(opaque)
    try:
        obj, signature = _signature(target)
        hints = typing.get_type_hints(obj.__init__ if inspect.isclass(obj) else obj)
    except Exception:  # unknown target or unresolvable hints: the target reports it when built
        return None
    # a dataclass target's own fields may declare ranges (:func:`ranged`): kept
    declared = (
        {f.name: dict(f.metadata) for f in dataclasses.fields(obj)}
        if dataclasses.is_dataclass(obj)
        else {}
    )
    fields_: list[Any] = []
    for name, param in signature.parameters.items():
        if name == "self" or param.kind in (param.VAR_POSITIONAL, param.VAR_KEYWORD):
            continue
        tp, metadata = _config_type(hints.get(name, Any), opaque)
        metadata = {**metadata, **declared.get(name, {})}
        fields_.append((name, tp, dataclasses.field(default=MISSING, metadata=metadata)))
    label = getattr(obj, "__qualname__", str(target))
    schema = dataclasses.make_dataclass(label.replace(".", "_"), fields_)
    schema.__qualname__ = label
    return schema


def _signature(target: str | Callable[..., Any]) -> tuple[Any, inspect.Signature]:
    """The object ``target`` names and the signature a call of it takes (a class: its
    constructor's, without ``self``)."""
    from hydra.utils import get_object

    obj = get_object(target) if isinstance(target, str) else target
    return obj, inspect.signature(obj)


def takes_any_keyword(target: str | Callable[..., Any]) -> bool:
    """Whether ``target`` accepts ``**kwargs``."""
    try:
        params = _signature(target)[1].parameters.values()
    except Exception:
        return True
    return any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params)


def check_target(
    node: DictConfig,
    key: str,
    opaque: Iterable[type] = (),
    also: Mapping[str, Sequence[Any]] | None = None,
) -> None:
    """Check one ``_target_`` node's parameters against :func:`target_schema` of its target.

    Child nodes with their own ``_target_`` are left to their own check; ``also`` maps full
    keys to extra values accepted there besides the annotation's (e.g. a value resolved when
    the run starts)."""
    target = node.get("_target_")
    schema = target_schema(str(target), opaque) if isinstance(target, str) else None
    if schema is None:
        return
    names = [f.name for f in dataclasses.fields(schema)]
    loose = takes_any_keyword(str(target))
    values: dict[str, Any] = {}
    for name in node:
        name = str(name)
        if name.startswith("_") or (loose and name not in names):
            continue
        if name not in names:
            raise SchemaError(_join(key, name), ", ".join(names), unknown=True, owner=str(target))
        if OmegaConf.is_missing(node, name):
            continue
        raw = node._get_node(name)
        if isinstance(raw, DictConfig) and "_target_" in raw:
            continue  # built by its own target, checked on its own
        if also and str(node[name]) in map(str, also.get(_join(key, name), ())):
            continue
        values[name] = _plain(node[name])
    check(values, schema, key)


def check_targets(
    cfg: DictConfig,
    sections: Sequence[str],
    opaque: Iterable[type] = (),
    also: Mapping[str, Sequence[Any]] | None = None,
) -> None:
    """:func:`check_target` for every ``_target_`` node under the top-level ``sections`` of
    ``cfg`` that are present."""
    opaque = tuple(opaque)
    for section in sections:
        if section in cfg and not OmegaConf.is_missing(cfg, section):
            _check_tree(cfg[section], section, opaque, also)


def _check_tree(
    node: Any, key: str, opaque: tuple[type, ...], also: Mapping[str, Sequence[Any]] | None
) -> None:
    if isinstance(node, ListConfig):
        for i in range(len(node)):
            if not OmegaConf.is_missing(node, i):
                _check_tree(node[i], _join(key, i), opaque, also)
        return
    if not isinstance(node, DictConfig):
        return
    if "_target_" in node:
        check_target(node, key, opaque, also)
    for name in node:
        if not str(name).startswith("_") and not OmegaConf.is_missing(node, name):
            child = node[name]
            if isinstance(child, (DictConfig, ListConfig)):
                _check_tree(child, _join(key, str(name)), opaque, also)

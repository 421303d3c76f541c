"""Checking values against a schema: a config node (:func:`validate`, :func:`check`) or a
settings object built in Python (:func:`check_fields`, what a settings dataclass's
``__post_init__`` calls). Types by OmegaConf's structured merge, then the range metadata and
the values as written by a walk over the schema; every problem one :class:`SchemaError` naming
the full key, built from OmegaConf's exception attributes, never from its message text."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any, Union

from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from omegaconf.errors import (
    ConfigKeyError,
    MissingMandatoryValue,
    OmegaConfBaseException,
    ValidationError,
)

from .fields import (
    _MAPPINGS,
    _SCALARS,
    _SEQUENCES,
    NEEDS,
    SchemaError,
    _describe,
    _hints,
    _optional,
    describe,
    repeats_refused,
    structured,
)


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


def check_fields(settings: Any, key: str = "") -> None:
    """Check a settings dataclass object built in Python against its own fields' types and
    range metadata (a settings class calls it from ``__post_init__``): the same rules, and the
    same :class:`SchemaError` lines, as a config checked by :func:`check` (``key``: the config
    section's dotted path, if any)."""
    cls = type(settings)
    hints = _hints(cls)
    for f in dataclasses.fields(cls):
        value = getattr(settings, f.name)
        if isinstance(value, tuple):
            value = list(value)
        _check_value(_plain(value), hints[f.name], dict(f.metadata), _join(key, f.name))


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
    if inner is Any and isinstance(value, (list, tuple)):
        _check_repeats(list(value), Any, metadata, tp, where)  # one item or a list of them
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
        _check_repeats(value, element, metadata, tp, where)
        each = {k: v for k, v in metadata.items() if k in ("min", "max", "gt", "lt", "text")}
        for i, item in enumerate(value):
            _check_value(item, element, each, _join(where, i))
        return
    if origin in _MAPPINGS and isinstance(value, Mapping) and len(args) == 2:
        for name, item in value.items():
            _check_value(item, args[1], {}, _join(where, str(name)))
        return
    _check_range(value, tp, metadata, where)


def _check_repeats(
    value: list[Any], element: Any, metadata: dict[str, Any], tp: Any, where: str
) -> None:
    """The list's duplicate policy (:func:`~.fields.repeats_refused`)."""
    if not repeats_refused(element, metadata):
        return
    seen: list[Any] = []
    for item in value:
        if item in seen:
            expected = describe(tp, {**metadata, "unique": True})
            raise SchemaError(where, f"{expected} ({item!r} is listed twice)", value)
        seen.append(item)


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


C_INT_MAX = 2**31 - 1
"""The largest integer a setting may hold without a bound of its own: the libraries behind the
settings (OpenCV, ONNX Runtime, NumPy's indices) take them as C ints, and a count past it is
no run that ends (``slam.tracker.ransac_iterations=2147483648``)."""


def _check_range(value: Any, tp: Any, metadata: dict[str, Any], where: str) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return
    low, high = metadata.get("min"), metadata.get("max")
    above, below = metadata.get("gt"), metadata.get("lt")
    past = isinstance(value, int) and not -C_INT_MAX - 1 <= value <= C_INT_MAX
    if past and _optional(tp)[0] is int:
        bound = {"max": C_INT_MAX} if value > 0 else {"min": -C_INT_MAX - 1}
        if (value > 0 and high is None and below is None) or (
            value < 0 and low is None and above is None
        ):
            raise SchemaError(where, describe(tp, {**metadata, **bound}), value)
    if (
        (low is not None and not value >= low)
        or (high is not None and not value <= high)
        or (above is not None and not value > above)
        or (below is not None and not value < below)
    ):
        raise SchemaError(where, describe(tp, metadata), value)


def unused_settings(values: Any, schema: type, key: str = "") -> list[str]:
    """One line per setting of ``values`` (a mapping or DictConfig checked against the
    dataclass ``schema``) that is set to other than its default while the boolean field its
    metadata ``needs`` is false: accepted, but it changes nothing (``slam.map.octomap_resolution``
    without ``slam.map.octomap``)."""
    plain = _plain(values) or {}
    lines: list[str] = []
    for f in dataclasses.fields(schema):
        where = _join(key, f.name)
        value = plain.get(f.name, MISSING)
        needs = f.metadata.get(NEEDS)
        if needs and plain.get(needs) is False and value is not MISSING and _changed(f, value):
            default = _default(f)
            section = dataclasses.is_dataclass(default) and isinstance(value, Mapping)
            keys = changed_keys(value, default, where) if section else [where]
            lines.append(unused_line(keys, f"{_join(key, needs)} is false"))
        inner, _ = _optional(_hints(schema)[f.name])
        if dataclasses.is_dataclass(inner) and isinstance(value, Mapping):
            lines += unused_settings(value, inner, where)  # type: ignore[arg-type]
    return lines


def changed_keys(section: Mapping[str, Any], default: Any, where: str = "") -> list[str]:
    """The full keys (under ``where``) of the settings in ``section`` whose values differ from
    those of ``default``, an instance of the section's dataclass."""
    defaults = _plain(dataclasses.asdict(default))
    return [_join(where, k) for k, v in section.items() if v != defaults.get(k)]


def unused_line(keys: Sequence[str], condition: str) -> str:
    """The warning for settings ``keys`` that change nothing while ``condition`` holds (one
    form for every such warning: :func:`unused_settings`' and the scripts' own)."""
    verb = "is set but changes" if len(keys) == 1 else "are set but change"
    return f"{', '.join(keys)} {verb} nothing while {condition}"


def _default(f: dataclasses.Field) -> Any:
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


def _changed(f: dataclasses.Field, value: Any) -> bool:
    """Whether ``value`` differs from the default of ``f`` (a section: in any key it gives)."""
    default = _default(f)
    if dataclasses.is_dataclass(default) and isinstance(value, Mapping):
        return bool(changed_keys(value, default))
    return bool(value != _plain(default))


def check_overrides_written(cfg: DictConfig, overrides: Sequence[str]) -> None:
    """The command line's values as written, for a config typed while Hydra composed it (a
    schema in the ConfigStore): OmegaConf has already turned ``no`` / ``off`` / ``1`` into a
    boolean and ``'3'`` into an integer there, so :func:`check` cannot see them; the schemas
    checked after composing refuse them. One :class:`SchemaError` naming the key, as theirs."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf.nodes import BooleanNode, FloatNode, IntegerNode

    kinds = {BooleanNode: bool, IntegerNode: int, FloatNode: float}
    for override in OverridesParser.create().parse_overrides(list(overrides)):
        if override.is_delete() or override.is_sweep_override():
            continue
        key = override.key_or_group
        parent, _, leaf = key.rpartition(".")
        try:
            owner = OmegaConf.select(cfg, parent) if parent else cfg
            node = owner._get_node(leaf) if isinstance(owner, DictConfig) else None
        except OmegaConfBaseException:  # not a key of the config (a group, a package)
            continue
        tp = next((t for kind, t in kinds.items() if isinstance(node, kind)), None)
        value = override.value()
        if isinstance(value, str) and "${" in value:  # an interpolation, resolved later
            continue
        if tp is not None and value is not None and not _written_as(tp, value):
            finite = tp is float and isinstance(value, float)  # inf, nan: a number, not finite
            raise SchemaError(key, "a finite number" if finite else _SCALARS[tp], value)

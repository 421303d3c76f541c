"""Schemas of ``_target_`` nodes, derived from their target's parameter annotations
(:func:`target_schema`, :func:`check_target`, :func:`check_targets`): what a config can express
(numbers, booleans, strings, ``null``, literals, lists of those) is judged; a parameter whose
annotation admits other objects is left to the target. Ranges come from ``Annotated[...,
Range(...)]`` annotations, a dataclass target's :func:`~.fields.ranged` fields, or, for a
library's class whose annotations we cannot change, :func:`declare`."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, Literal, Optional, Union

from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf

from uss_slam.core.ranges import MAX_SEED

from .checking import _join, _plain, check
from .fields import _MAPPINGS, _SCALARS, _SEQUENCES, Range, SchemaError

SEED_RANGE = {"min": 0, "max": MAX_SEED}
"""The range of a target's integer parameter named ``seed`` unless it declares its own: the
range of every other seed (``seed``, which ``data.seed: ${seed}`` and the methods' seeds take,
so a seed ``seed=null`` draws is one every seed key takes)."""

DECLARED: dict[str, dict[str, dict[str, Any]]] = {}
"""``{target path: {parameter: range metadata}}`` declared by :func:`declare`."""


def declare(target: str, **ranges: Range) -> None:
    """Ranges of the parameters of a library's class or function (``_target_`` path) whose
    annotations say only ``float``: ``declare("torch.optim.SGD", momentum=Range(min=0))``."""
    DECLARED.setdefault(target, {}).update({k: r.metadata for k, r in ranges.items()})


def _config_type(annotation: Any, opaque: tuple[type, ...]) -> tuple[Any, dict[str, Any]]:
    """The OmegaConf type (and range metadata) of a parameter annotation: what a config value
    can be checked against; ``Any`` where the annotation admits objects a config cannot hold
    or judge. ``opaque``: classes that are never config values (dropped from unions)."""
    if annotation in _SCALARS:
        return annotation, {}
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        tp, metadata = _config_type(args[0], opaque)
        for extra in args[1:]:
            if isinstance(extra, Range):
                metadata = {**metadata, **extra.metadata}
        return tp, metadata
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
        hints = typing.get_type_hints(
            obj.__init__ if inspect.isclass(obj) else obj, include_extras=True
        )
    except Exception:  # unknown target or unresolvable hints: the target reports it when built
        return None
    # a dataclass target's own fields may declare ranges (:func:`ranged`): kept
    declared = (
        {f.name: dict(f.metadata) for f in dataclasses.fields(obj)}
        if dataclasses.is_dataclass(obj)
        else {}
    )
    path = target if isinstance(target, str) else f"{obj.__module__}.{obj.__qualname__}"
    for name, metadata in DECLARED.get(path, {}).items():
        declared[name] = {**declared.get(name, {}), **metadata}
    fields_: list[Any] = []
    for name, param in signature.parameters.items():
        if name == "self" or param.kind in (param.VAR_POSITIONAL, param.VAR_KEYWORD):
            continue
        tp, metadata = _config_type(hints.get(name, Any), opaque)
        if name == "seed" and tp in (int, Optional[int]):  # noqa: UP045
            metadata = {**SEED_RANGE, **metadata}  # one bound for every seed
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

    if isinstance(target, str):
        _import_module_of(target)
    obj = get_object(target) if isinstance(target, str) else target
    return obj, inspect.signature(obj)


def _import_module_of(target: str) -> None:
    """Import the module ``target`` lives in, so that a package it needs that is not installed
    raises its own ``ModuleNotFoundError`` (the launcher's one line) rather than Hydra's logged
    "Error getting object" lines; a prefix that is no module is left to Hydra's lookup."""
    parts = target.split(".")
    for end in range(len(parts) - 1, 0, -1):
        name = ".".join(parts[:end])
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as error:
            if error.name is not None and (name == error.name or name.startswith(f"{error.name}.")):
                continue  # no such module: the target's module is a shorter prefix
            raise
        except Exception:
            return  # Hydra's lookup reports it
        return


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

"""A schema inside Hydra: its structured config in the ConfigStore (:func:`register`), and
one line for an OmegaConf error raised while a config is composed (:func:`omegaconf_error_line`)."""

from __future__ import annotations

import dataclasses
import enum
from typing import Optional

from omegaconf import DictConfig, ListConfig
from omegaconf.errors import (
    ConfigAttributeError,
    ConfigKeyError,
    ConfigTypeError,
    KeyValidationError,
    MissingMandatoryValue,
    OmegaConfBaseException,
    ValidationError,
)

from ..errors import UssSlamError
from .fields import SchemaError, _hints, describe, structured


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
    merged = isinstance(error, ConfigTypeError) and error.object_type in (list, dict)
    if merged and isinstance(error.parent_node, ListConfig):
        return f"{key}: expected a list, got a mapping"  # a mapping merged into a list node
    if merged and isinstance(error.parent_node, DictConfig):
        return f"{key}: expected a mapping, got a list"  # and back
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


def register(group: str, name: str, schema: type) -> None:
    """Store ``schema`` in Hydra's ConfigStore as ``<group>/<name>`` (for a defaults list:
    ``- /<group>/<name>@<package>``); idempotent."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(group=group, name=name, node=structured(schema))


def check_interpolations(cfg: DictConfig | ListConfig, prefix: str = "") -> None:
    """Resolve every interpolation of ``cfg`` (``${oc.env:SEQ}``, ``${now:...}``, ``${a.b}``)
    before any work: one that cannot be resolved (a variable that is not set, a key that does
    not exist) is a :class:`SchemaError` naming the key that holds it, not OmegaConf's text
    without a key (:class:`UssSlamError`). A missing mandatory value (``???``) is left to the schema's own check."""
    keys = range(len(cfg)) if isinstance(cfg, ListConfig) else list(cfg.keys())
    for key in keys:
        full = f"{prefix}[{key}]" if isinstance(key, int) else f"{prefix}.{key}".lstrip(".")
        node = cfg._get_node(key)
        try:
            value = cfg[key]
        except MissingMandatoryValue:
            continue
        except OmegaConfBaseException as error:
            if node is None or not node._is_interpolation():
                raise
            text = str(error.msg or error).strip().splitlines()
            detail = text[0].split("resolving interpolation: ")[-1].strip("'\"")
            raise UssSlamError(f"{full}: cannot resolve {node._value()} ({detail})") from None
        if isinstance(value, (DictConfig, ListConfig)):
            check_interpolations(value, full)

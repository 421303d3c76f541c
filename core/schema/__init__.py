"""Typed config schemas: the one layer that checks the values of every command's config.

A schema is a dataclass: its annotations give the types (``int``, ``float``, ``bool``, ``str``,
Enums, ``Optional``, lists, nested dataclasses), OmegaConf enforces them, and value ranges are
field metadata (:func:`ranged`: ``min``, ``max``, ``gt``, ``lt``, ``choices``, ``length``,
``nonempty``, ``unique``). Schemas are registered in Hydra's ConfigStore (:func:`register`)
where a config composes them in its defaults list, or applied to a composed config
(:func:`validate`); a settings dataclass built in Python checks itself with the same metadata
(:func:`check_fields` from its ``__post_init__``).

Objects built with ``_target_`` are checked against a schema derived from their target's
parameter annotations (:func:`target_schema`, :func:`check_targets`; ranges as
``Annotated[int, Range(min=1)]``, or :func:`declare` for a library's class).

Every problem is a :class:`SchemaError`, one line ``<key>: expected <what>, got <value>``,
built from OmegaConf's exception attributes (``full_key``, ``value``, the schema's field type),
never from its message text.

The jobs, one module each: :mod:`.fields` (what a schema declares), :mod:`.checking` (checking
values), :mod:`.compose` (Hydra's ConfigStore, errors while composing), :mod:`.targets`
(``_target_`` nodes).
"""

from .checking import (
    changed_keys,
    check,
    check_fields,
    check_overrides_written,
    unused_line,
    unused_settings,
    validate,
)
from .compose import omegaconf_error_line, register
from .fields import (
    MAX_THREADS,
    RANGE_KEYS,
    THREADS,
    Range,
    SchemaError,
    describe,
    machine_threads,
    ranged,
    repeats_refused,
    structured,
)
from .targets import check_target, check_targets, declare, takes_any_keyword, target_schema

__all__ = [
    "MAX_THREADS",
    "RANGE_KEYS",
    "THREADS",
    "Range",
    "SchemaError",
    "check",
    "check_fields",
    "check_overrides_written",
    "check_target",
    "check_targets",
    "declare",
    "describe",
    "machine_threads",
    "omegaconf_error_line",
    "ranged",
    "register",
    "repeats_refused",
    "structured",
    "takes_any_keyword",
    "unused_settings",
    "unused_line",
    "changed_keys",
    "target_schema",
    "validate",
]

"""Values written into Hydra overrides (``key=value``): what the plan and the launcher both
hand to ``uss-train`` and the job runner."""

from __future__ import annotations

from typing import Any

from uss_slam.core.paths import hydra_quoted


def hydra_value(value: Any) -> str:
    """A Hydra override value: quoted strings, plain numbers / booleans / null, lists."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(hydra_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{hydra_value(v)}" for k, v in value.items()) + "}"
    return hydra_quoted(str(value))


def config_error_line(error: Exception, what: str) -> str | None:
    """The line of an error composing or checking a job's config (``<key>: <what was
    expected>``; ``what`` names the config: ``training``, ``uss-slam``), None for an error that
    is not about the config."""
    from uss_slam.core.cli import hydra_error_line
    from uss_slam.core.errors import UssSlamError

    line = str(error).strip() if isinstance(error, UssSlamError) else hydra_error_line(error)
    if line is None:
        return None
    key = _not_in_struct(error)
    if key is not None:
        return f"{key}: not a key of the {what} config (a new key needs +{key}=VALUE)"
    return line


def _not_in_struct(error: BaseException) -> str | None:
    """The key of an override that names no key of a plain (struct) config node, which ``+``
    would add; None otherwise (a typed section's keys are fixed)."""
    import dataclasses

    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    seen: list[BaseException] = []
    current: BaseException | None = error
    while current is not None and all(current is not c for c in seen):
        seen.append(current)
        if isinstance(current, (ConfigAttributeError, ConfigKeyError)) and current.full_key:
            if not dataclasses.is_dataclass(current.object_type):
                return str(current.full_key)
            return None
        current = current.__cause__ or current.__context__
    return None

"""Values written into Hydra overrides (``key=value``): what the plan and the launcher both
hand to ``uss-train`` and the job runner."""

from __future__ import annotations

import re
from typing import Any


def _typed(text: str) -> bool:
    """True when Hydra would read ``text`` unquoted as a number, boolean or null."""
    if text.lower() in ("true", "false", "null"):
        return True
    try:
        float(text)
    except ValueError:
        return False
    return True


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
    text = str(value)
    if re.fullmatch(r"[A-Za-z0-9_\-./+@%]+", text) and not _typed(text):
        return text  # a plain Hydra string: no quotes needed
    text = text.replace("\\", "\\\\").replace("'", "\\'")
    return f"'{text}'"


_NOT_IN_STRUCT = re.compile(r"(?:(?P<path>\S+): )?Key '(?P<key>[^']+)' is not in struct")


def config_error_line(error: Exception, what: str) -> str | None:
    """The line of an error composing or checking a job's config (``<key>: <what was
    expected>``; ``what`` names the config: ``training``, ``uss-slam``), None for an error that
    is not about the config."""
    from uss_slam.core.cli import hydra_error_line
    from uss_slam.core.errors import UssSlamError

    line = str(error).strip() if isinstance(error, UssSlamError) else hydra_error_line(error)
    if line is None:
        return None
    found = _NOT_IN_STRUCT.fullmatch(line)
    if found:
        key = found["path"] or found["key"]
        return f"{key}: not a key of the {what} config (a new key needs +{key}=VALUE)"
    return line

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

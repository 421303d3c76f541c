"""The shipped adaptation methods: the options of the config group ``model/method``.

A method is one class in ``train/methods/<name>.py`` and one ``configs/model/method/<name>.yaml``
whose ``_target_`` names that class; this module lists the group's files, so the experiment grid
and the every-method tests find a new method without another list to edit. Reading the names
loads no torch (``uss-experiments`` checks its grid without it); :func:`method_class` imports the
class.
"""

from __future__ import annotations

import functools
from pathlib import Path

import yaml

from uss_slam.core.errors import DataFormatError, UssSlamError

METHOD_GROUP = Path(__file__).resolve().parents[1] / "configs" / "model" / "method"
"""The config group's folder: one ``<name>.yaml`` per method."""
BASELINE = "source_only"
"""The method every table compares with ("without ATL"): listed first."""


def method_names() -> tuple[str, ...]:
    """Every shipped method: source-only first, then the others in alphabetical order."""
    names = sorted(p.stem for p in METHOD_GROUP.glob("*.yaml"))
    return tuple(sorted(names, key=lambda name: name != BASELINE))


@functools.cache
def method_target(name: str) -> str:
    """The ``_target_`` of ``model/method=<name>``: the class path of the method (at the top of
    the file, or under ``method:`` in a ``# @package model`` file that also sets other keys)."""
    path = METHOD_GROUP / f"{name}.yaml"
    if not path.is_file():
        raise UssSlamError(
            f"model/method={name}: no such method; accepted: {', '.join(method_names())}"
        )
    node = yaml.safe_load(path.read_text()) or {}
    for candidate in (node, node.get("method") if isinstance(node, dict) else None):
        if isinstance(candidate, dict) and isinstance(candidate.get("_target_"), str):
            return candidate["_target_"]
    raise DataFormatError(
        path, "expected a _target_ naming the method's class (top level or method._target_)"
    )


def method_class(name: str) -> type:
    """The class of ``model/method=<name>`` (imports it, and so torch)."""
    from hydra.utils import get_class

    return get_class(method_target(name))


def trains_discriminators(name: str) -> bool:
    """Whether ``model/method=<name>`` trains the two discriminators (its class says so)."""
    return bool(method_class(name).trains_discriminators)

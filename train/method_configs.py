"""The shipped adaptation methods: the options of the config group ``model/method``.

A method is one class in ``train/methods/<name>.py`` and one ``configs/model/method/<name>.yaml``
whose ``_target_`` names that class; this module lists the group's files, so the experiment grid
and the every-method tests find a new method without another list to edit. Reading the names
and :func:`trains_discriminators` loads no torch (``uss-experiments`` checks its grid without
it: importing torch, torchvision and Lightning costs seconds of CPU); :func:`method_class`
imports the class.
"""

from __future__ import annotations

import ast
import functools
import importlib.machinery
import importlib.util
import inspect
import logging
import sys
from pathlib import Path
from typing import Any

import yaml

from uss_slam.core.errors import DataFormatError, UssSlamError

log = logging.getLogger(__name__)

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
    node = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
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
    """Whether ``model/method=<name>`` trains the two discriminators (its class says so).

    Read from the source of the class and its bases (a ``trains_discriminators = True`` in the
    class body), without importing them; where the source does not say it plainly (a computed
    value, several bases, a base it cannot find), from the imported class."""
    found = _class_constant(method_target(name), "trains_discriminators")
    if found is None:
        return bool(method_class(name).trains_discriminators)
    return bool(found)


def _module_source(module: str) -> tuple[ast.Module, str] | None:
    """The parsed source of ``module`` and its package (for its relative imports), found
    without running it or a package above it that is not imported yet (the imports of
    ``uss_slam.train.methods`` load torch); None where there is no Python source."""
    parts = module.split(".")
    spec = None
    for i in range(1, len(parts) + 1):
        name, parent = ".".join(parts[:i]), ".".join(parts[: i - 1])
        if i == 1 or parent in sys.modules:
            spec = importlib.util.find_spec(name)
        elif spec is not None and spec.submodule_search_locations is not None:
            locations = list(spec.submodule_search_locations)
            spec = importlib.machinery.PathFinder.find_spec(name, locations)
        else:
            return None
        if spec is None:
            return None
    if spec is None or not str(spec.origin).endswith(".py"):
        return None
    try:
        tree = ast.parse(Path(str(spec.origin)).read_text(encoding="utf-8"))
    except (OSError, SyntaxError, ValueError):
        return None
    is_package = spec.submodule_search_locations is not None
    return tree, module if is_package else module.rpartition(".")[0]


def _class_constant(target: str, attr: str, depth: int = 0) -> object | None:
    """The constant ``attr`` of the class ``target`` (``module.Class``) as its source or its
    single base's (followed through ``from ... import``) assigns it, else None (not plainly
    readable: a computed value, several bases, a metaclass, no source)."""
    module, _, name = target.rpartition(".")
    found = _module_source(module) if module and depth < 10 else None
    if found is None:
        return None
    tree, package = found
    for node in tree.body:
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if (alias.asname or alias.name) == name:
                    relative = "." * node.level + (node.module or "")
                    source = importlib.util.resolve_name(relative, package)
                    return _class_constant(f"{source}.{alias.name}", attr, depth + 1)
        if not isinstance(node, ast.ClassDef) or node.name != name:
            continue
        for statement in node.body:
            if isinstance(statement, ast.AnnAssign | ast.Assign):
                targets = getattr(statement, "targets", [getattr(statement, "target", None)])
                if any(isinstance(t, ast.Name) and t.id == attr for t in targets):
                    value = statement.value
                    return value.value if isinstance(value, ast.Constant) else None
        if len(node.bases) != 1 or not isinstance(node.bases[0], ast.Name) or node.keywords:
            return None
        return _class_constant(f"{module}.{node.bases[0].id}", attr, depth + 1)
    return None


def method_parameters(target: str) -> tuple[str, ...]:
    """The settings a method class takes (its ``__init__``'s keyword parameters)."""
    from hydra.utils import get_class

    signature = inspect.signature(get_class(target).__init__)
    return tuple(
        name
        for name, p in signature.parameters.items()
        if name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    )


def unused_method_settings(node: Any) -> list[str]:
    """Check the keys of the ``model.method`` config node against its method's settings.

    A key that another shipped method takes (an experiment that sets
    ``model.method.discriminator.ndf`` for whichever method runs, applied to ``source_only``) is
    accepted but changes nothing: it is returned (and logged as a warning) for the caller to
    drop. A key no shipped method takes is a typo: one line naming it and the accepted ones.

    Args:
        node: the ``model.method`` mapping (a ``DictConfig`` or dict) with its ``_target_``.

    Returns:
        The keys to drop before instantiating.
    """
    target = node.get("_target_") if hasattr(node, "get") else None
    if not isinstance(target, str):
        return []
    own = set(method_parameters(target))
    known = {k for name in method_names() for k in method_parameters(method_target(name))}
    chosen = next((n for n in method_names() if method_target(n) == target), target)
    unused = []
    for key in node:
        if str(key).startswith("_") or key in own:
            continue
        if key not in known:
            accepted = ", ".join(sorted(own)) or "none"
            raise UssSlamError(
                f"model.method.{key}: not a setting of model/method={chosen}; its settings: "
                f"{accepted}"
            )
        log.warning(
            "model.method.%s: model/method=%s has no such setting (another method's); ignored",
            key,
            chosen,
        )
        unused.append(str(key))
    return unused

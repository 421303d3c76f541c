"""The orchestration modules import one way: no two modules of ``pipelines/`` import each other,
directly or through others, counting the imports inside functions (a lazy import hides a cycle
from Python, not from a reader)."""

from __future__ import annotations

from pathlib import Path

from shared_helpers import import_cycle, read_imports

PIPELINES = Path(__file__).resolve().parents[2] / "pipelines"
PACKAGE = "uss_slam.pipelines"


def _module(path: Path) -> str:
    parts = path.relative_to(PIPELINES).with_suffix("").parts
    parts = parts[:-1] if parts[-1] == "__init__" else parts
    return ".".join((PACKAGE, *parts))


def _imports(path: Path, modules: set[str]) -> set[str]:
    """The modules of ``pipelines/`` that the file imports (a package counts as its
    ``__init__``; ``from . import x`` counts as module ``x`` when it is one)."""
    name = _module(path)
    lines = read_imports(path.read_text(), name, path.name == "__init__.py")
    found = set().union(*(line.modules() for line in lines))
    return {m for m in found if m in modules and m != name}


def _graph() -> dict[str, set[str]]:
    files = sorted(PIPELINES.rglob("*.py"))
    modules = {_module(p) for p in files}
    return {_module(p): _imports(p, modules) for p in files}


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert import_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert import_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_no_import_cycle_in_pipelines() -> None:
    graph = _graph()
    assert f"{PACKAGE}.experiments.plan" in graph and graph[f"{PACKAGE}.experiments.plan"]
    # package __init__ files re-export their modules: an edge from a module up to its own
    # package is the package importing the module, not a cycle between two modules
    for name, imported in graph.items():
        graph[name] = {m for m in imported if not name.startswith(m + ".")}
    assert import_cycle(graph) is None, " -> ".join(import_cycle(graph) or [])


def test_no_pipelines_module_is_named_after_one_of_its_users() -> None:
    # the data recipe that uss-demo and uss-experiments share is not the demo's
    users = {
        _module(p)
        for p in PIPELINES.rglob("*.py")
        if f"{PACKAGE}.synthetic_data" in _imports(p, {f"{PACKAGE}.synthetic_data"})
    }
    assert f"{PACKAGE}.demo" in users
    assert any(u.startswith(f"{PACKAGE}.experiments.") for u in users)
    assert not (PIPELINES / "demo_data.py").exists()

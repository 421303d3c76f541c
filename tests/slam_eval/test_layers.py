"""The sub-packages of ``slam_eval`` import each other one way only: no import cycle between
them, and tracking and mapping never import each other (both sit on the shared map,
``slam_eval/map/``, as ORB-SLAM2's ``Tracking`` and ``LocalMapping`` on its ``Map``)."""

from __future__ import annotations

from pathlib import Path

from shared_helpers import import_cycle, read_imports

SLAM_EVAL = Path(__file__).resolve().parents[2] / "slam_eval"
PACKAGE = "uss_slam.slam_eval"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SLAM_EVAL).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([PACKAGE, *parts])


def _imports(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (``TYPE_CHECKING`` and function-level
    imports included)."""
    lines = read_imports(path.read_text(), _module_name(path), path.name == "__init__.py")
    return set().union(*(line.modules() for line in lines))


def _sub_package(module: str) -> str | None:
    """``tracking`` for ``uss_slam.slam_eval.tracking.tracker``; None for the root modules
    (``config``, ``run``, ``geometry``, ...) and anything outside slam_eval."""
    if not module.startswith(PACKAGE + "."):
        return None
    head = module[len(PACKAGE) + 1 :].split(".")[0]
    return head if (SLAM_EVAL / head).is_dir() else None


def sub_package_graph() -> dict[str, set[str]]:
    """``{sub-package: the other sub-packages its files import}``."""
    graph: dict[str, set[str]] = {}
    for path in sorted(SLAM_EVAL.rglob("*.py")):
        own = _sub_package(_module_name(path))
        if own is None:
            continue
        targets = {_sub_package(m) for m in _imports(path)}
        graph.setdefault(own, set()).update(t for t in targets if t and t != own)
    return graph


def test_the_graph_sees_the_sub_packages_and_their_imports() -> None:
    graph = sub_package_graph()
    assert {"tracking", "mapping", "map", "filters", "systems", "scoring"} <= set(graph)
    assert "map" in graph["tracking"] and "map" in graph["mapping"]
    assert import_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_tracking_and_mapping_do_not_import_each_other() -> None:
    graph = sub_package_graph()
    assert "mapping" not in graph["tracking"], "slam_eval/tracking imports slam_eval/mapping"
    assert "tracking" not in graph["mapping"], "slam_eval/mapping imports slam_eval/tracking"


def test_scoring_reads_the_map_products_not_the_back_end() -> None:
    graph = sub_package_graph()
    assert "products" in graph["scoring"]
    assert "mapping" not in graph["scoring"], "slam_eval/scoring imports slam_eval/mapping"
    assert "mapping" not in graph["products"], "slam_eval/products imports slam_eval/mapping"


def test_matching_and_optimisation_sit_below_tracking_and_the_back_end() -> None:
    graph = sub_package_graph()
    assert "matching" in graph["tracking"] and "optim" in graph["matching"]
    for low in ("matching", "optim"):
        for high in ("tracking", "mapping", "systems", "filters"):
            assert high not in graph[low], f"slam_eval/{low} imports slam_eval/{high}"


def test_loop_closing_borrows_no_tracker() -> None:
    """The back end works on the map it is handed and on the matching package, with no
    interface of the tracker's (no Protocol, no mixin)."""
    for path in sorted((SLAM_EVAL / "mapping").rglob("*.py")):
        text = path.read_text()
        assert "Protocol" not in text and "tracker" not in _imports(path), path.name
    assert not (SLAM_EVAL / "tracking" / "place_matching.py").exists()


def test_no_import_cycle_between_sub_packages() -> None:
    cycle = import_cycle(sub_package_graph())
    assert cycle is None, "import cycle between slam_eval sub-packages: " + " -> ".join(cycle)

"""No product file over 600 lines (DESIGN.md's cap): every Python file git tracks outside
``tests/``, whichever package or folder it is in (a new one is covered without an edit); and no
function over 80 lines in ``slam_eval/`` and ``train/``."""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
MAX_LINES = 600


def product_files() -> list[Path]:
    """Every ``.py`` file git tracks (or would add) outside ``tests/``."""
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.py"],
        cwd=REPO, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if out.returncode != 0:  # not a git checkout (an unpacked sdist): the folders themselves
        names = [p.relative_to(REPO).as_posix() for p in REPO.rglob("*.py")]
    else:
        names = out.stdout.split()
    return [
        REPO / name
        for name in sorted(names)
        if not name.startswith(("tests/", ".venv/", "build/")) and (REPO / name).is_file()
    ]


def lines_over(limit: int, files: list[Path], root: Path = REPO) -> list[str]:
    """``"<path under root>: N lines"`` of each of ``files`` longer than ``limit`` lines."""
    long = []
    for path in files:
        count = len(path.read_text(encoding="utf-8").splitlines())
        if count > limit:
            long.append(f"{path.relative_to(root)}: {count} lines")
    return long


def test_no_product_file_over_600_lines() -> None:
    files = product_files()
    assert len(files) > 100  # the tree was found
    assert lines_over(MAX_LINES, files) == []


def test_the_check_reports_a_long_file(tmp_path: Path) -> None:
    (tmp_path / "long.py").write_text("x = 1\n" * (MAX_LINES + 1))
    (tmp_path / "short.py").write_text("x = 1\n" * MAX_LINES)
    files = sorted(tmp_path.glob("*.py"))
    assert lines_over(MAX_LINES, files, tmp_path) == ["long.py: 601 lines"]


@pytest.mark.parametrize("folder", ["core", "slam_eval", "train"])
def test_product_files_include_every_package(folder: str) -> None:
    assert any(p.relative_to(REPO).parts[0] == folder for p in product_files())


MAX_FUNCTION_LINES = 80
FUNCTION_CAPPED = ("slam_eval", "train")
"""The packages whose functions stay within :data:`MAX_FUNCTION_LINES` (the SLAM harness and the
training loop, where steps are meant to be read one at a time)."""


def functions_over(limit: int, files: list[Path], root: Path = REPO) -> list[str]:
    """``"<path>:<line> <name>: N lines"`` of each function (or method) of ``files`` longer than
    ``limit`` lines, its decorators and docstring included."""
    long = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                count = (node.end_lineno or node.lineno) - first + 1
                if count > limit:
                    long.append(
                        f"{path.relative_to(root)}:{node.lineno} {node.name}: {count} lines"
                    )
    return long


def test_no_function_over_80_lines_in_the_slam_harness_and_training() -> None:
    files = [p for p in product_files() if p.relative_to(REPO).parts[0] in FUNCTION_CAPPED]
    assert len(files) > 50  # both packages were found
    assert functions_over(MAX_FUNCTION_LINES, files) == []


def test_the_function_check_reports_a_long_function(tmp_path: Path) -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES - 1))
    (tmp_path / "m.py").write_text(f"def fits():\n{body}\n\n@staticmethod\ndef long():\n{body}")
    assert functions_over(MAX_FUNCTION_LINES, [tmp_path / "m.py"], tmp_path) == [
        f"m.py:{MAX_FUNCTION_LINES + 4} long: {MAX_FUNCTION_LINES + 1} lines"
    ]

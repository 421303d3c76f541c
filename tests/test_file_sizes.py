"""No product file over 600 lines (DESIGN.md's cap): every Python file git tracks outside
``tests/``, whichever package or folder it is in (a new one is covered without an edit)."""

from __future__ import annotations

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

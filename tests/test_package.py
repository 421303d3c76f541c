"""The package layout: sub-packages of the ``uss_slam`` namespace mapped onto the top-level folders."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# Every top-level folder with an __init__.py (the config tree's too) installs as uss_slam.<folder>.
PACKAGES = {f"uss_slam.{p.parent.name}": p.parent.name for p in sorted(REPO.glob("*/__init__.py"))}
SHIPPED_SUFFIXES = (".py", ".yaml", ".pt")  # .pt: package data (pipelines/assets/)


def shipped_files() -> set[str]:
    """The wheel paths of every .py and .yaml file under the package folders and configs/, in
    whichever sub-folder (a new sub-package or config group must ship without an edit)."""
    return {
        f"uss_slam/{p.relative_to(REPO).as_posix()}"
        for folder in PACKAGES.values()
        for p in (REPO / folder).rglob("*")
        if p.suffix in SHIPPED_SUFFIXES and p.is_file() and "__pycache__" not in p.parts
    }


def test_setup_maps_every_package_folder() -> None:
    """setup.py's ``FOLDERS`` (read without running setup) are the package folders and configs/."""
    tree = ast.parse((REPO / "setup.py").read_text(encoding="utf-8"))
    (folders,) = [
        ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and ast.unparse(node.targets[0]) == "FOLDERS"
    ]
    assert "configs" in PACKAGES.values()
    assert sorted(folders) == sorted(PACKAGES.values())


@pytest.mark.parametrize(("module", "folder"), PACKAGES.items())
def test_subpackage_resolves_to_repo_folder(module: str, folder: str) -> None:
    imported = __import__(module, fromlist=["_"])
    assert Path(imported.__file__).resolve() == REPO / folder / "__init__.py"


def test_regular_wheel_maps_folders_into_namespace(tmp_path: Path) -> None:
    """``pip install .`` installs from a wheel: it must hold ``uss_slam/<pkg>/...`` files and
    every .py and .yaml file of every package folder and sub-folder (setup.py finds them), and
    the build must print no setuptools warning."""
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(REPO),
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(tmp_path),
            "-v",
        ],
        capture_output=True,
        text=True,
    )
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    warnings = [
        line.strip()
        for line in (build.stdout + build.stderr).splitlines()
        if re.search(r"(?i)warn|deprecat|would be ignored", line)
        # PYTHONDONTWRITEBYTECODE: setuptools says it compiles nothing, not a packaging issue
        and "byte-compiling is disabled" not in line
        # pip's own note on a local index location of this machine
        and "is ignored: it is neither a file nor a directory" not in line
        # a module's name (core/library_warnings.py) in the lines of the files copied
        and not re.match(r"\s*(copying|adding) ", line)
    ]
    assert not warnings, "\n".join(warnings)
    (wheel,) = tmp_path.glob("uss_slam-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for module in PACKAGES:
        assert f"{module.replace('.', '/')}/__init__.py" in names
    expected = shipped_files()
    assert any(n.startswith("uss_slam/configs/") for n in expected)
    assert expected <= names, sorted(expected - names)
    assert not any(
        n.startswith(("models/", "datasets/", "tests/", "benchmarks/", "studies/", "testing/"))
        for n in names
    )

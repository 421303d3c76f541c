"""The package layout: sub-packages of the ``uss_slam`` namespace mapped onto the top-level folders."""

from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = {
    "uss_slam.core": "core",
    "uss_slam.models": "models",
    "uss_slam.datasets": "datasets",
    "uss_slam.synthetic": "synthetic",
    "uss_slam.train": "train",
    "uss_slam.export": "export",
    "uss_slam.slam_eval": "slam_eval",
    "uss_slam.pipelines": "pipelines",
}


@pytest.mark.parametrize(("module", "folder"), PACKAGES.items())
def test_subpackage_resolves_to_repo_folder(module: str, folder: str) -> None:
    imported = __import__(module, fromlist=["_"])
    assert Path(imported.__file__).resolve() == REPO / folder / "__init__.py"


def test_regular_wheel_maps_folders_into_namespace(tmp_path: Path) -> None:
    """``pip install .`` installs from a wheel: it must hold ``uss_slam/<pkg>/...`` files and
    every shipped config, and the build must print no setuptools warning (such as a config
    folder missing from pyproject's ``packages``)."""
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
    ]
    assert not warnings, "\n".join(warnings)
    (wheel,) = tmp_path.glob("uss_slam-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for module, folder in PACKAGES.items():
        prefix = module.replace(".", "/")
        assert f"{prefix}/__init__.py" in names
        # sub-packages too: each needs its own entry in pyproject's `packages`
        expected = {
            f"{prefix}/{p.relative_to(REPO / folder).as_posix()}"
            for p in (REPO / folder).rglob("*.py")
        }
        assert expected <= names, sorted(expected - names)
    configs = {
        f"uss_slam/configs/{p.relative_to(REPO / 'configs').as_posix()}"
        for p in (REPO / "configs").rglob("*.yaml")
    }
    assert configs <= names, sorted(configs - names)
    assert not any(n.startswith(("models/", "datasets/", "tests/")) for n in names)

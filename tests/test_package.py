"""The package layout: sub-packages of the ``uss_slam`` namespace mapped onto the top-level folders."""

from __future__ import annotations

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


def test_slam_runtime_never_imports_torch() -> None:
    code = (
        "import importlib, pkgutil, sys\n"
        "import uss_slam.slam_eval as pkg\n"
        "for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        "    importlib.import_module(info.name)\n"
        "bad = sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.'))\n"
        "print(len(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "0", out.stdout + out.stderr


def test_regular_wheel_maps_folders_into_namespace(tmp_path: Path) -> None:
    """``pip install .`` installs from a wheel: it must hold ``uss_slam/<pkg>/...`` files."""
    subprocess.run(
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
            "-q",
        ],
        check=True,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("uss_slam-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for module, folder in PACKAGES.items():
        prefix = module.replace(".", "/")
        assert f"{prefix}/__init__.py" in names
        expected = {
            f"{prefix}/{p.relative_to(REPO / folder).as_posix()}"
            for p in (REPO / folder).glob("*.py")
        }
        assert expected <= names, sorted(expected - names)
    assert not any(n.startswith(("models/", "datasets/", "tests/")) for n in names)

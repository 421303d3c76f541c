"""Import floors: a package imports only packages on lower floors (never one on its own floor).

``FLOORS`` is the one table of floors (the README's architecture table is checked against it).
The check is static (every ``import`` in every ``.py`` file of a package, including imports
inside functions and ``TYPE_CHECKING`` blocks, parsed with ``ast``) and, for the torch-free
packages, also at runtime: importing every module of the package in a fresh interpreter must
not load torch.
"""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import NamedTuple

import pytest
from shared_helpers import read_imports

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"

# fmt: off
# package:     (floor, the uss_slam packages it may import, torch-free)
FLOORS: dict[str, tuple[int, tuple[str, ...], bool]] = {
    "core":      (0, (), True),  # third-party: numpy, scipy, cv2, yaml, hydra/omegaconf, tqdm
    "datasets":  (1, ("core",), False),
    "synthetic": (1, ("core",), True),
    "models":    (1, ("core",), False),
    "train":     (2, ("core", "datasets", "models"), False),
    "export":    (2, ("core", "models"), False),
    "slam_eval": (2, ("core",), True),
    "pipelines": (3, ("core", "datasets", "synthetic", "models", "train", "export", "slam_eval"),
                  False),
    "testing":   (4, ("core", "datasets", "synthetic", "models", "train", "export", "slam_eval",
                      "pipelines"), False),
}
# fmt: on
# All torch-free and used by every runtime package already: scipy for rotations (core.tum_io),
# hydra / omegaconf for the console scripts' error and multirun handling (core.cli); isal for
# PNG decoding (core.png_inflate: ISA-L's inflate, about twice zlib's speed).
CORE_THIRD_PARTY = frozenset(
    {"numpy", "scipy", "cv2", "yaml", "hydra", "omegaconf", "tqdm", "isal"}
)
# Importing any of these loads torch.
TORCH_FAMILY = frozenset(
    {"torch", "torchvision", "torchmetrics", "lightning", "pytorch_lightning", "lightning_fabric"}
)
# Shipped data (the Hydra config tree), importable from any floor.
DATA_PACKAGES = frozenset({"configs"})
# Breaches that are known and waiting for their fix: (file, imported module) -> what to do.
KNOWN_VIOLATIONS: dict[tuple[str, str], str] = {}


def imported_modules(source: str, module: str) -> list[tuple[int, str]]:
    """``(line, absolute module)`` for every import in ``source`` (the file of ``module``,
    e.g. ``uss_slam.core.tum_io``; a package's ``__init__`` is ``<package>.__init__``)."""
    package = module.removesuffix(".__init__")
    found: list[tuple[int, str]] = []
    for line in read_imports(source, package, is_package=module.endswith(".__init__")):
        if line.module == "uss_slam" and line.names:  # `from uss_slam import datasets`
            found += [(line.line, f"uss_slam.{name}") for name in line.names]
        else:
            found.append((line.line, line.module))
    return sorted(found)


def rule_broken(package: str, imported: str) -> str | None:
    """Why ``package`` may not import ``imported`` (an absolute module name), or None."""
    floor, allowed, torch_free = FLOORS[package]
    top, _, rest = imported.partition(".")
    if top == "uss_slam":
        target = rest.partition(".")[0]
        if target in (package, *DATA_PACKAGES, *allowed):
            return None
        if target not in FLOORS:
            return f"uss_slam.{target} has no floor (add it to FLOORS in tests/test_floors.py)"
        other = FLOORS[target][0]
        if other > floor:
            return f"{target} is on a higher floor ({other} > {floor})"
        if other == floor:
            return f"{target} is on the same floor ({floor}): same-floor packages stay independent"
        return f"{package} may import only {', '.join(allowed) or 'no other uss_slam package'}"
    if torch_free and top in TORCH_FAMILY:
        return f"{package} is torch-free" + ("" if top == "torch" else f" ({top} loads torch)")
    if package == "core" and top not in sys.stdlib_module_names | CORE_THIRD_PARTY:
        return f"core imports only the standard library, {', '.join(sorted(CORE_THIRD_PARTY))}"
    return None


class Violation(NamedTuple):
    file: str  # relative to the repository
    line: int
    package: str
    imported: str
    reason: str

    def __str__(self) -> str:
        floor = FLOORS[self.package][0]
        return (
            f"{self.file}:{self.line}: {self.package} (floor {floor}) imports {self.imported}: "
            f"{self.reason}"
        )


def violations(package: str, path: Path, source: str) -> list[Violation]:
    """Each import of ``source`` (the file ``path`` inside ``package``) that breaks a rule."""
    relative = path.relative_to(REPO / package).with_suffix("")
    parts = [p for p in relative.parts if p != "__init__"]
    module = ".".join(["uss_slam", package, *parts])
    if relative.name == "__init__":
        module += ".__init__"  # so that `from . import x` resolves inside the package
    file = path.relative_to(REPO).as_posix()
    return [
        Violation(file, line, package, imported, reason)
        for line, imported in imported_modules(source, module)
        if (reason := rule_broken(package, imported))
    ]


def test_every_package_has_a_floor() -> None:
    folders = {p.parent.name for p in REPO.glob("*/__init__.py")} - DATA_PACKAGES
    assert folders == set(FLOORS), "top-level packages and FLOORS differ"


def test_table_allows_only_lower_floors() -> None:
    for package, (floor, allowed, _) in FLOORS.items():
        higher = [a for a in allowed if FLOORS[a][0] >= floor]
        assert not higher, f"FLOORS: {package} (floor {floor}) may not import {higher}"


def tree_violations() -> list[Violation]:
    return [
        v
        for package in FLOORS
        for f in sorted((REPO / package).rglob("*.py"))
        for v in violations(package, f, f.read_text(encoding="utf-8"))
    ]


@pytest.mark.parametrize("package", sorted(FLOORS))
def test_package_imports_only_lower_floors(package: str) -> None:
    assert list((REPO / package).rglob("*.py")), f"no Python files under {package}/"
    broken = [
        str(v)
        for v in tree_violations()
        if v.package == package and (v.file, v.imported) not in KNOWN_VIOLATIONS
    ]
    assert not broken, "import floor rules broken:\n" + "\n".join(broken)


def test_known_violations_still_exist() -> None:
    """An entry of KNOWN_VIOLATIONS that was fixed must leave the list."""
    found = {(v.file, v.imported) for v in tree_violations()}
    fixed = sorted(set(KNOWN_VIOLATIONS) - found)
    assert not fixed, f"fixed, remove from KNOWN_VIOLATIONS: {fixed}"


@pytest.mark.parametrize("package", sorted(p for p, row in FLOORS.items() if row[2]))
def test_torch_free_package_loads_no_torch(package: str) -> None:
    """Import every module of the package in a fresh interpreter; name the first that loads
    torch (or any module of the torch family)."""
    code = textwrap.dedent(f"""
        import importlib, pathlib, pkgutil, sys
        FAMILY = {sorted(TORCH_FAMILY)!r}
        def loaded():
            return sorted(m for m in sys.modules if m.partition('.')[0] in FAMILY)
        pkg = importlib.import_module('uss_slam.{package}')
        names = [pkg.__name__] + sorted(
            i.name for i in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'))
        for name in names:
            importlib.import_module(name)
            if loaded():
                print(name, 'loads', ', '.join(loaded()[:3]))
                break
        else:
            files = list(pathlib.Path(pkg.__file__).parent.rglob('*.py'))
            print('ok', len(names), len(files))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("ok "), out.stdout + out.stderr
    # the package, its sub-packages and modules: one name per .py file, so none was missed
    _, names, files = out.stdout.split()
    assert names == files, out.stdout


def _check(package: str, source: str, name: str = "mod.py") -> list[str]:
    return violations(package, REPO / package / name, textwrap.dedent(source))


@pytest.mark.parametrize(
    ("package", "source", "reason"),
    [
        ("core", "import torch\n", "core is torch-free"),
        (
            "core",
            "import matplotlib.pyplot\n",
            "core imports only the standard library, cv2, hydra, isal, numpy, omegaconf, scipy, tqdm, yaml",
        ),
        ("core", "import PIL.Image\n", "core imports only the standard library"),
        ("synthetic", "def f():\n    import torchvision\n", "synthetic is torch-free"),
        ("slam_eval", "from lightning.pytorch import Trainer\n", "slam_eval is torch-free"),
        ("slam_eval", "from uss_slam.export import onnx_export\n", "same floor (2)"),
        ("slam_eval", "from uss_slam.pipelines.demo import x\n", "higher floor (3 > 2)"),
        ("models", "from uss_slam import datasets\n", "same floor (1)"),
        ("datasets", "from uss_slam.train.module import X\n", "higher floor (2 > 1)"),
        ("export", "from uss_slam.datasets.transforms import X\n", "may import only core, models"),
        ("train", "from uss_slam.widgets import X\n", "uss_slam.widgets has no floor"),
        ("core", "from ..datasets import base\n", "higher floor (1 > 0)"),
        (
            "train",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from uss_slam.pipelines import demo\n",
            "higher floor (3 > 2)",
        ),
    ],
)
def test_checker_reports_file_line_and_rule(package: str, source: str, reason: str) -> None:
    (found,) = map(str, _check(package, source))
    line = source.count("\n")
    assert found.startswith(f"{package}/mod.py:{line}: {package} (floor {FLOORS[package][0]}) ")
    assert reason in found


@pytest.mark.parametrize(
    ("package", "source"),
    [
        ("core", "import os, json\nimport numpy as np\nimport cv2\nfrom yaml import safe_load\n"),
        ("core", "from .errors import UssSlamError\nfrom . import classes\n"),
        ("synthetic", "from PIL import Image\nfrom uss_slam.core.errors import UssSlamError\n"),
        (
            "train",
            "import torch\nfrom uss_slam.datasets import base\nfrom uss_slam.models import x\n",
        ),
        ("pipelines", "from uss_slam.train import train\nfrom uss_slam.slam_eval import run\n"),
        ("slam_eval", "import onnxruntime\nfrom uss_slam import core\n"),
    ],
)
def test_checker_accepts_allowed_imports(package: str, source: str) -> None:
    assert _check(package, source) == []


def test_relative_import_in_package_init_stays_inside() -> None:
    assert _check("core", "from . import errors\n", "__init__.py") == []
    assert _check("core", "from .. import train\n", "__init__.py") != []


def readme_floors() -> dict[str, tuple[int, set[str], bool]]:
    """The README's table: ``| floor | `package/` | role | may import |`` rows."""
    rows = {}
    for line in README.read_text(encoding="utf-8").splitlines():
        match = re.fullmatch(r"\| (\d) \| `(\w+)/` \|.*\| ([^|]+) \|", line)
        if match:
            floor, package, may = int(match[1]), match[2], match[3]
            allowed = (
                {p for p, row in FLOORS.items() if row[0] < floor}  # every lower floor
                if "everything" in may
                else {word for word in re.findall(r"\w+", may) if word in FLOORS}
            )
            rows[package] = (floor, allowed, bool(re.search(r"\((no|never) torch\)", may)))
    return rows


def test_readme_table_matches_floors() -> None:
    expected = {p: (floor, set(allowed), free) for p, (floor, allowed, free) in FLOORS.items()}
    assert readme_floors() == expected

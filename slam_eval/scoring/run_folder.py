"""The output folder of a ``uss-slam`` run: files written atomically, and a manifest written last.

Rules, so that a folder never mixes two runs unnoticed:

- Nothing is written before the first SLAM run of an invocation has finished (a run that fails
  earlier, on a bad config or sequence, leaves the earlier run's folder exactly as it was).
- :meth:`RunFolder.start` then removes the earlier run's outputs, its manifest ``run.json``
  first: a folder without ``run.json`` is always an unfinished (or killed) run.
- Every file goes to a temporary sibling (``.uss-slam-<name>.<random>.tmp``) and is renamed onto
  its name when complete, so no file is ever half-written under its own name.
- :meth:`RunFolder.commit` writes ``run.json`` last: ``{"status": "complete", "files":
  {relative path: sha256}, ...}``, ``.hydra/`` included. :func:`verify_run` checks a folder
  against it (missing manifest, missing / changed / unlisted output files); a rerun into the
  folder cleans up whatever a killed run left.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from uss_slam.core.files import atomic_path, file_sha256
from uss_slam.core.tum_io import StrPath

MANIFEST = "run.json"
TMP_PREFIX = ".uss-slam-"
OUTPUT_NAMES = (
    "trajectory.txt",
    "metrics.json",
    "report.md",
    "trajectory.png",
    "ate.png",
    "map.ply",
    "octomap.ot",
    "comparison.md",
    "comparison.json",
)
"""Files a run writes into its folder (and into each sub-folder of a comparison)."""
HYDRA_FILES = (".hydra/config.yaml", ".hydra/hydra.yaml", ".hydra/overrides.yaml")


class RunFolder:
    """Writes one run's outputs under ``root`` (see the module docstring)."""

    def __init__(self, root: StrPath) -> None:
        # Absolute: the files recorded under it may be named relative to the working directory.
        self.root = Path(root).absolute()
        self.files: list[str] = []

    @classmethod
    def start(cls, root: StrPath) -> RunFolder:
        """Remove the earlier run's outputs (manifest first) and return a folder to write to."""
        folder = cls(root)
        folder.root.mkdir(parents=True, exist_ok=True)
        clear_outputs(folder.root)
        return folder

    def _relative(self, path: StrPath) -> str:
        path = Path(path)
        if not path.is_absolute():  # relative to the working directory, or else to the folder
            cwd_relative = path.absolute()
            path = cwd_relative if cwd_relative.is_relative_to(self.root) else self.root / path
        full = path
        try:
            return full.relative_to(self.root).as_posix()
        except ValueError:
            raise ValueError(f"{full} is not inside the run folder {self.root}") from None

    @contextmanager
    def writing(self, path: StrPath) -> Iterator[Path]:
        """:func:`~uss_slam.core.files.atomic_path` (temporary prefix :data:`TMP_PREFIX`, what
        :func:`clear_outputs` removes after a killed run) for an output (``path`` relative to
        the folder or inside it), recorded for the manifest."""
        relative = self._relative(path)
        (self.root / relative).parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.root / relative, prefix=TMP_PREFIX) as tmp:
            yield tmp
        if relative not in self.files:
            self.files.append(relative)

    def write_text(self, path: StrPath, text: str) -> Path:
        with self.writing(path) as tmp:
            tmp.write_text(text)
        return self.root / self._relative(path)

    def record(self, path: StrPath) -> None:
        """Record a file some other writer placed atomically (e.g. a plot)."""
        relative = self._relative(path)
        if relative not in self.files:
            self.files.append(relative)

    def commit(self, **info: Any) -> Path:
        """Write ``run.json`` (every recorded file with its sha256, and ``info``) last."""
        manifest = {
            "status": "complete",
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            **info,
            "files": {name: file_sha256(self.root / name) for name in sorted(self.files)},
        }
        with atomic_path(self.root / MANIFEST, prefix=TMP_PREFIX) as tmp:
            tmp.write_text(json.dumps(manifest, indent=2) + "\n")
        return self.root / MANIFEST


def _listed_files(root: Path) -> list[str]:
    try:
        data = json.loads((root / MANIFEST).read_text())
        files = data.get("files", {}) if isinstance(data, dict) else {}
        return [str(name) for name in files]
    except (OSError, ValueError):
        return []


def _inside(root: Path, relative: str) -> Path | None:
    path = (root / relative).resolve()
    return path if path.is_relative_to(root.resolve()) and path != root.resolve() else None


def _output_subfolders(root: Path) -> list[Path]:
    """Sub-folders holding a run's outputs (a comparison's runs), nothing else of the user's."""
    out = []
    for sub in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        names = {p.name for p in sub.iterdir()}
        ours = {n for n in names if n in OUTPUT_NAMES or n.startswith(TMP_PREFIX)}
        if ours & {"trajectory.txt", "metrics.json"} and ours == names:
            out.append(sub)
    return out


def clear_outputs(root: StrPath) -> None:
    """Remove a run's outputs from ``root``: ``run.json`` first, then the files it lists, the
    known output names (also in a comparison's sub-folders), ``.hydra/`` and leftover
    temporaries. Files of the user's that are none of these stay."""
    root = Path(root)
    if not root.is_dir():
        return
    listed = _listed_files(root)
    (root / MANIFEST).unlink(missing_ok=True)
    candidates = [*listed, *OUTPUT_NAMES, *HYDRA_FILES]
    for sub in _output_subfolders(root):
        candidates += [f"{sub.name}/{name}" for name in OUTPUT_NAMES]
    for relative in candidates:
        path = _inside(root, relative)
        if path is not None and path.is_file():
            path.unlink()
    for leftover in [*root.glob(f"{TMP_PREFIX}*"), *root.glob(f"*/{TMP_PREFIX}*")]:
        if leftover.is_file():
            leftover.unlink()
    for sub in sorted({(root / r).parent for r in candidates} - {root}, reverse=True):
        inside = _inside(root, sub.relative_to(root).as_posix())
        if inside is not None and sub.is_dir() and not any(sub.iterdir()):
            sub.rmdir()


def verify_run(root: StrPath) -> list[str]:
    """What is wrong with the run folder ``root`` (empty list: a complete, unchanged run).

    Checks: ``run.json`` present and complete; every listed file present with its sha256; no
    output file (known names, ``.hydra/``, temporaries) that the manifest does not list.
    """
    root = Path(root)
    manifest = root / MANIFEST
    if not manifest.is_file():
        return [f"{manifest}: missing (the run did not finish, or was killed)"]
    try:
        data = json.loads(manifest.read_text())
        files = dict(data["files"])
        status = data["status"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        return [f"{manifest}: not a uss-slam manifest ({err})"]
    problems = [] if status == "complete" else [f"{manifest}: status {status!r}"]
    for name, digest in files.items():
        path = root / name
        if not path.is_file():
            problems.append(f"{path}: listed in {MANIFEST} but missing")
        elif file_sha256(path) != digest:
            problems.append(f"{path}: changed since the run (sha256 differs from {MANIFEST})")
    present = [*OUTPUT_NAMES, *HYDRA_FILES]
    for sub in _output_subfolders(root):
        present += [f"{sub.name}/{name}" for name in OUTPUT_NAMES]
    for name in present:
        if (root / name).is_file() and name not in files:
            problems.append(f"{root / name}: not listed in {MANIFEST} (left by another run)")
    for leftover in [*root.glob(f"{TMP_PREFIX}*"), *root.glob(f"*/{TMP_PREFIX}*")]:
        problems.append(f"{leftover}: temporary file of an interrupted write")
    return problems

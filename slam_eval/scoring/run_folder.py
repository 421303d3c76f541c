"""The output folder of a ``uss-slam`` run: files written atomically, and a manifest written last.

Rules, so that a folder never mixes two runs unnoticed and a run that does not finish leaves the
earlier one as it was:

- A run's files are written into a hidden staging folder inside the run folder
  (``.uss-slam-new.<random>/``, :meth:`RunFolder.start`), each file atomically (a temporary
  sibling ``.uss-slam-<name>.<random>.tmp`` renamed onto its name when complete). A run that
  fails, is interrupted (Ctrl-C) or finds the disk full before :meth:`RunFolder.commit` leaves
  the earlier run's folder exactly as it was (the staging folder is removed; one left by a
  killed run is removed by the next run into the folder).
- :meth:`RunFolder.commit` then removes the earlier run's outputs, its manifest ``run.json``
  first (a folder without ``run.json`` is always an unfinished or killed run), moves the new
  files into place (renames: no space needed; Ctrl-C waits for them) and writes ``run.json``
  last: ``{"status": "complete", "files": {relative path: sha256}, ...}``, ``.hydra/``
  included. :func:`verify_run` checks a folder against it (missing manifest, missing /
  changed / unlisted output files); a rerun into the folder cleans up whatever a killed run
  left.

A :class:`RunFolder` made directly (``RunFolder(root)``, no staging) writes each file in place,
atomically, without a manifest.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from uss_slam.core.cli import interrupts_deferred
from uss_slam.core.errors import NoSpaceError
from uss_slam.core.files import atomic_path, file_sha256
from uss_slam.core.tum_io import StrPath

MANIFEST = "run.json"
TMP_PREFIX = ".uss-slam-"
STAGING_PREFIX = f"{TMP_PREFIX}new."
"""Name prefix of a run's staging folder inside the run folder."""
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
    """Writes one run's outputs under ``root`` (see the module docstring); with ``staging``
    (:meth:`start`), into that folder until :meth:`commit`."""

    def __init__(self, root: StrPath, staging: StrPath | None = None) -> None:
        # Absolute: the files recorded under it may be named relative to the working directory.
        self.root = Path(root).absolute()
        self.staging = None if staging is None else Path(staging).absolute()
        self.files: list[str] = []

    @classmethod
    def start(cls, root: StrPath) -> RunFolder:
        """A new run's folder in ``root``: its files go to a fresh staging folder (staging
        folders left by killed runs are removed) and replace the earlier run's at
        :meth:`commit`."""
        root = Path(root).absolute()
        root.mkdir(parents=True, exist_ok=True)
        remove_staging(root)
        staging = None  # a Ctrl-C or SIGTERM as it is made comes once it is owned, and takes it
        try:
            with interrupts_deferred():
                staging = tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=root)
                made = cls(root, staging)
        except BaseException:
            if staging is not None:
                shutil.rmtree(staging, ignore_errors=True)
            raise
        return made

    def __enter__(self) -> RunFolder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.discard()

    def discard(self) -> None:
        """Remove the staging folder and what it holds (nothing of the run is committed)."""
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None
            self.files.clear()

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

    def _target(self, relative: str) -> Path:
        """Where the output ``relative`` is written now (staging until :meth:`commit`)."""
        target = (self.staging or self.root) / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        return target

    def current(self, path: StrPath) -> Path:
        """Where the output ``path`` is now: in the staging folder until :meth:`commit`."""
        return (self.staging or self.root) / self._relative(path)

    @contextmanager
    def placing(self, path: StrPath) -> Iterator[Path]:
        """Yield where to write the output ``path`` (relative to the folder or inside it): in
        the staging folder until :meth:`commit`; its folder exists. For writers that place a
        file themselves, atomically (a plot); recorded for the manifest when the block ends
        normally. A full disk meanwhile is a :class:`NoSpaceError` naming ``path``."""
        relative = self._relative(path)
        try:
            yield self._target(relative)
        except NoSpaceError as error:
            raise NoSpaceError(self.root / relative, error.errno) from error
        if relative not in self.files:
            self.files.append(relative)

    @contextmanager
    def writing(self, path: StrPath) -> Iterator[Path]:
        """:meth:`placing` through :func:`~uss_slam.core.files.atomic_path` (temporary prefix
        :data:`TMP_PREFIX`, what :func:`clear_outputs` removes after a killed run): yields the
        temporary file to write."""
        with self.placing(path) as target, atomic_path(target, prefix=TMP_PREFIX) as tmp:
            yield tmp

    def write_text(self, path: StrPath, text: str) -> Path:
        with self.writing(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
        return self.root / self._relative(path)

    def commit(self, **info: Any) -> Path:
        """Replace the earlier run's outputs with the staged ones (moved in the order they
        were written) and write ``run.json`` (every recorded file with its sha256, and
        ``info``) last. Ctrl-C meanwhile waits until it is done."""
        with interrupts_deferred():
            if self.staging is not None:
                clear_outputs(self.root)
                for name in self.files:
                    final = self.root / name
                    final.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(self.staging / name, final)
                shutil.rmtree(self.staging, ignore_errors=True)
                self.staging = None
            manifest = {
                "status": "complete",
                "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                **info,
                "files": {name: file_sha256(self.root / name) for name in sorted(self.files)},
            }
            with atomic_path(self.root / MANIFEST, prefix=TMP_PREFIX) as tmp:
                tmp.write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
        return self.root / MANIFEST


def remove_staging(root: StrPath) -> list[Path]:
    """Remove the staging folders in ``root`` (left by killed runs: a live run holds the
    folder's lock); returns them."""
    root = Path(root)
    found = sorted(p for p in root.glob(f"{STAGING_PREFIX}*") if p.is_dir())
    for folder in found:
        shutil.rmtree(folder, ignore_errors=True)
    return found


def _listed_files(root: Path) -> list[str]:
    try:
        data = json.loads((root / MANIFEST).read_text(encoding="utf-8"))
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
    output file (known names, ``.hydra/``, temporaries) that the manifest does not list. (The
    staging folder of a run that did not finish is not part of the run checked.)
    """
    root = Path(root)
    manifest = root / MANIFEST
    if not manifest.is_file():
        return [f"{manifest}: missing (the run did not finish, or was killed)"]
    try:
        data = json.loads(manifest.read_text(encoding="utf-8"))
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
        if not (leftover.is_dir() and leftover.name.startswith(STAGING_PREFIX)):
            problems.append(f"{leftover}: temporary file of an interrupted write")
    return problems

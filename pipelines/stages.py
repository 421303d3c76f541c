"""Cached pipeline stages: a stage is an output folder, the key of its inputs and a completion
stamp written last, atomically.

A stage counts as complete only when its stamp holds the same key and its expected outputs
exist. Before a stage is (re)done its stamp is removed *first*, then its folder emptied; the stamp
is written only after the work returned. So a stage killed at any point (even while its old
folder is being deleted) has no stamp and is redone on the next run, never reused.

A stage with ``resume_from`` (a training: ``checkpoints/last.ckpt``) keeps the folder of an
interrupted run of the *same key* instead of emptying it, so its work can go on from that file:
:meth:`Stage.start` records the key in a start marker, :meth:`Stage.finish` removes it, and
:meth:`Stage.abandon` (a run that failed rather than was interrupted) removes it too, so that
the next run starts afresh.

    stage = Stage(out / "train" / "adapted", key={"overrides": [...]},
                  outputs=(Path("checkpoints/*.ckpt"),))
    progress = Progress(total=3)
    progress.run("train", "train adapted", lambda: run_stage(stage, work, force=False))
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uss_slam.core.files import write_json_atomic

TRAINING_OUTPUTS = ("checkpoints/last.ckpt",)
"""What a finished training stage holds: ``last.ckpt``, which every checkpoint policy falls
back to and every training writes (a ``best_*.ckpt`` alone is not a finished training: with
``last.ckpt`` deleted the stage is trained again, not reused)."""

STAMP = ".uss-demo.json"
"""Name of the completion stamp in a stage folder (JSON of the stage's key)."""

STARTED = ".uss-started.json"
"""Name of the start marker of a stage folder with ``resume_from`` (JSON of the key of the run
that started there and has neither finished nor failed)."""


@dataclass(frozen=True)
class Stage:
    """One cached step.

    ``folder``: the stage's own folder (emptied before the stage is redone when ``fresh``; holds
    the stamp). ``key``: everything its result depends on (JSON-able). ``outputs``: files that
    must exist for it to count as complete; a name may be a glob pattern (``checkpoints/*.ckpt``:
    at least one match); relative paths are inside ``folder``. ``resume_from``: the file (inside
    ``folder``) an interrupted run of the same key can go on from; its folder is then kept.
    """

    folder: Path
    key: Mapping[str, Any]
    outputs: tuple[Path, ...] = ()
    fresh: bool = True
    stamp_name: str = STAMP
    resume_from: Path | None = None

    @property
    def stamp(self) -> Path:
        return self.folder / self.stamp_name

    @property
    def started(self) -> Path:
        return self.folder / STARTED

    def resumable(self) -> Path | None:
        """``folder / resume_from`` when an interrupted run of this same key left it (its start
        marker holds this key and no stamp says it finished), else ``None``."""
        if self.resume_from is None or self.stamp.is_file():
            return None
        try:
            recorded = json.loads(self.started.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            return None
        path = self.folder / self.resume_from
        return path if recorded == json.loads(json.dumps(self.key)) and path.is_file() else None

    def complete(self) -> bool:
        """True when the stamp holds this key and every expected output exists."""
        return self.stale() is None

    def stale(self) -> str | None:
        """Why the stage must be (re)done, or ``None`` when it is complete: ``"not done yet"``
        (no readable stamp), ``"<keys> changed"`` (the top-level entries of the key that differ
        from the stamp's) or ``"<output> missing"``."""
        try:
            recorded = json.loads(self.stamp.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            return "not done yet"
        key = json.loads(json.dumps(self.key))  # compare as JSON (tuples = lists)
        if recorded != key:
            return f"{', '.join(_changed(key, recorded))} changed"
        for p in self.outputs:
            found = self.folder / p  # an absolute p stays itself
            if not any(found.parent.glob(found.name)):
                return f"{found} missing"
        return None

    def start(self, resume: bool = True) -> None:
        """Invalidate (stamp first), then empty the folder when ``fresh``; the folder exists.
        With ``resume`` (and ``resume_from``) the folder of an interrupted run of the same key is
        kept instead, so that the work goes on from its ``resume_from`` file."""
        keep = resume and self.resumable() is not None
        self.stamp.unlink(missing_ok=True)
        if self.fresh and self.folder.exists() and not keep:
            shutil.rmtree(self.folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        if self.resume_from is not None:
            write_json_atomic(self.started, dict(self.key))

    def finish(self) -> None:
        """Mark complete: the stamp, written atomically (then the start marker goes)."""
        write_json_atomic(self.stamp, dict(self.key))
        self.started.unlink(missing_ok=True)

    def abandon(self) -> None:
        """A run that failed (not one interrupted): the next run of the stage starts afresh."""
        self.started.unlink(missing_ok=True)


def staging_folder(folder: Path) -> Path:
    """The hidden sibling a stage with an earlier result works in (``.<name>.next``): the earlier
    result stays whole until :func:`swap_in` replaces it with a successful new one."""
    return folder.with_name(f".{folder.name}.next")


def _retired(folder: Path) -> Path:
    return folder.with_name(f".{folder.name}.old")


def swap_in(new: Path, folder: Path) -> None:
    """Replace ``folder`` by ``new`` (its staging folder, complete): two renames in one parent
    folder, then the earlier result is deleted. Killed between the renames, :func:`recover`
    puts the earlier result back."""
    old = _retired(folder)
    if old.exists():
        shutil.rmtree(old)
    if folder.exists():
        folder.rename(old)
    new.rename(folder)
    if old.exists():
        shutil.rmtree(old)


def recover(folder: Path) -> None:
    """Undo a :func:`swap_in` killed half-way: the earlier result back in ``folder``."""
    old = _retired(folder)
    if old.exists() and not folder.exists():
        old.rename(folder)


def _changed(new: Any, old: Any, prefix: str = "") -> list[str]:
    """The dotted names of the entries that differ between two JSON values (mappings are
    followed down; anything else that differs is named as a whole)."""
    if not (isinstance(new, dict) and isinstance(old, dict)):
        return [prefix or "key"]
    names = []
    for k in sorted({*new, *old}):
        if new.get(k) != old.get(k):
            names += (
                _changed(new.get(k), old.get(k), f"{prefix}{k}.")
                if k in new and k in old
                else [f"{prefix}{k}"]
            )
    return [n.rstrip(".") for n in names]


def run_stage(stage: Stage, work: Callable[[], str], force: bool = False) -> str:
    """``"reused"`` if ``stage`` is complete (and not ``force``), else start it, run ``work``
    and mark it complete; returns ``work``'s status text, prefixed with why an earlier result
    was redone (``"redone (sequence changed): ..."``; nothing when there was none)."""
    why = stage.stale()
    if not force and why is None:
        return "reused"
    had_result = stage.stamp.is_file()
    stage.start(resume=not force)  # a stage with resume_from: its work goes on from the file
    try:
        status = work()
    except Exception:
        stage.abandon()
        raise
    stage.finish()
    if force and had_result:
        return f"redone (--force): {status}"
    return f"redone ({why}): {status}" if had_result and why is not None else status


class Progress:
    """Prints ``[k/N] what ...`` before and ``[k/N] what: status in X s (total Y s)`` after each
    step; ``times`` sums the seconds per step name."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.count = 0
        self.start = time.perf_counter()
        self.times: dict[str, float] = {}

    def run(self, name: str, what: str, fn: Callable[[], str]) -> None:
        self.count += 1
        print(f"[{self.count}/{self.total}] {what} ...", flush=True)
        t0 = time.perf_counter()
        status = fn()
        spent = time.perf_counter() - t0
        self.times[name] = self.times.get(name, 0.0) + spent
        total = time.perf_counter() - self.start
        print(
            f"[{self.count}/{self.total}] {what}: {status} in {spent:.1f} s (total {total:.1f} s)",
            flush=True,
        )

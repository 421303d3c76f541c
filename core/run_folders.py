"""A Hydra app's run folder, checked and owned before Hydra writes into it.

:class:`RunFolderCheck` is a Hydra callback (``hydra.callbacks``): when a run starts (before
Hydra creates the run folder, writes its record ``.hydra/`` and opens its log file there) it
refuses a folder that cannot be created or written (:func:`uss_slam.core.paths.output_folder`:
its length, links that loop or point nowhere, a file in the way, a read-only location) or that
holds another console script's outputs (:func:`uss_slam.core.files.check_output_owner`), and
takes the folder's lock (:func:`uss_slam.core.files.output_lock`) for the whole run: a second
run started into the same folder (two ``uss-train`` calls with one ``hydra.run.dir``) stops
with exit code 2 and one line before it writes anything. The lock is released when the run
ends (:func:`release_run_folders`, which :func:`uss_slam.core.cli.run_hydra_app` calls), and
by the kernel when the process ends in any other way.
"""

from __future__ import annotations

import contextlib
import os
import sys
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uss_slam.core.errors import UssSlamError

_held: list[AbstractContextManager[Any]] = []
"""The run-folder locks this process holds (entered :func:`~uss_slam.core.files.output_lock`
blocks), released by :func:`release_run_folders`."""


class RefusedRunFolder(BaseException):
    """A Hydra app's run folder refused before Hydra writes into it (:class:`RunFolderCheck`).

    A ``BaseException``: Hydra turns an ``Exception`` of a callback into a warning and goes
    on; :func:`uss_slam.core.cli.run_hydra_app` prints the one line of :attr:`error` and
    exits with its code (2 for a folder another run holds)."""

    def __init__(self, error: UssSlamError) -> None:
        super().__init__(str(error))
        self.error = error


@dataclass
class _Before:
    """A run folder as it was when the run started (before Hydra wrote into it)."""

    folder: Path
    existed: bool
    names: set[str] = field(default_factory=set)
    """The folder's entries then (an existing folder)."""
    record: dict[str, bytes] = field(default_factory=dict)
    """Hydra's record of the earlier run (``.hydra/<file>`` -> its bytes)."""
    logs: dict[str, int] = field(default_factory=dict)
    """The earlier logs (``<job>.log``) -> their sizes."""
    made_from: Path | None = None
    """A new folder's nearest folder that existed: the folders below it are Hydra's."""


_started: list[_Before] = []
"""The run folders of the runs this process started (:meth:`RunFolderCheck.on_run_start`)."""


def _hydra_own(name: str) -> bool:
    return name == ".hydra" or name.endswith(".log")


def _remembered(folder: Path) -> _Before | None:
    """``folder`` as it is now; None if it cannot be read (the checks say why, or the run may
    not need to: nothing of it is then undone)."""
    try:
        return _looked_at(folder)
    except OSError:
        return None


def _looked_at(folder: Path) -> _Before:
    if not folder.is_dir():
        made_from = folder.parent
        while not made_from.exists() and made_from != made_from.parent:
            made_from = made_from.parent
        return _Before(folder, existed=False, made_from=made_from)
    names = set(os.listdir(folder))
    record = {f".hydra/{p.name}": p.read_bytes() for p in (folder / ".hydra").glob("*")
              if p.is_file()} if (folder / ".hydra").is_dir() else {}  # fmt: skip
    logs = {n: (folder / n).stat().st_size for n in names if n.endswith(".log")}
    return _Before(folder, existed=True, names=names, record=record, logs=logs)


def undo_hydra_records() -> None:
    """A single run that failed or was interrupted before its task wrote anything: Hydra's own
    files in its run folder (the ``.hydra/`` record and the empty log it opened) are undone,
    so that a refused run writes nothing: a new folder is removed (with the folders Hydra made
    above it), an existing one gets its earlier record and logs back. A folder that holds
    anything else new (a checkpoint of a training that failed later) is left as it is: its
    log tells what happened."""
    import shutil

    while _started:
        before = _started.pop()
        with contextlib.suppress(OSError):
            new = set(os.listdir(before.folder)) - before.names
            if any(not _hydra_own(n) for n in new):
                continue
            if not before.existed:
                shutil.rmtree(before.folder)
                _emptied.append(before)  # its parents once its lock (beside it) is gone
                continue
            for name in new:
                if name == ".hydra":
                    shutil.rmtree(before.folder / name)
                else:
                    os.remove(before.folder / name)
            for rel in {str(p.relative_to(before.folder)) for p in
                        (before.folder / ".hydra").glob("*")} - set(before.record):  # fmt: skip
                os.remove(before.folder / rel)
            for rel, data in before.record.items():
                (before.folder / rel).write_bytes(data)
            for name, size in before.logs.items():
                os.truncate(before.folder / name, size)


_emptied: list[_Before] = []
"""New run folders removed by :func:`undo_hydra_records`; :func:`release_run_folders` removes
the folders Hydra made above them once the locks beside them are gone."""


def _remove_made_parents() -> None:
    while _emptied:
        before = _emptied.pop()
        above = before.folder.parent
        with contextlib.suppress(OSError):  # (one that is not empty stops here)
            while before.made_from is not None and above != before.made_from:
                above.rmdir()
                above = above.parent


def forget_run_folders() -> None:
    """The run succeeded: its folders' earlier state is no longer needed."""
    _started.clear()


def release_run_folders() -> None:
    """Release every run-folder lock this process took (last taken first)."""
    while _held:
        _held.pop().__exit__(None, None, None)
    _remove_made_parents()


def started_folder_again(prog: str) -> None:
    """Inside a Hydra task: with ``hydra.job.chdir=true`` Hydra has changed into the run folder,
    where every relative path the user gave (``sequence.path=w/tgt``) would be looked for. The
    scripts write their outputs by their keys (``out_dir``, the run folder) and read relative
    paths from the folder they were started in, as without it: the task goes back there, with
    one warning that the key changes nothing (Hydra returns to it after the task anyway)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized() or not HydraConfig.get().job.get("chdir"):
        return
    started = str(HydraConfig.get().runtime.cwd)
    if os.path.realpath(os.getcwd()) != os.path.realpath(started):
        os.chdir(started)
    print(
        f"{prog}: warning: hydra.job.chdir=true changes nothing: relative paths are read from the "
        "folder the script was started in, and the outputs go to the folders their keys name",
        file=sys.stderr,
    )


LOG_KEY = "hydra.job_logging.handlers.file.filename"


def _log_file(config: Any, folder: str) -> None:
    """The log file a user placed outside the run folder (:data:`LOG_KEY`) is checked as an
    output file, before Hydra's logging opens it (its error was a traceback); a folder of it
    that does not exist is refused (the logging would not make it)."""
    from omegaconf import OmegaConf

    from uss_slam.core.paths import PathError, output_file

    try:
        name = OmegaConf.select(config, LOG_KEY, default=None, throw_on_resolution_failure=False)
    except Exception:  # noqa: BLE001 (${hydra:runtime...}, not set yet: Hydra's own folder)
        return
    if not isinstance(name, str) or not name:
        return
    path, run = Path(os.path.abspath(name)), Path(os.path.abspath(folder))
    if path.parent == run or run in path.parents:
        return  # in the run folder, which Hydra makes
    try:
        if not path.parent.is_dir():
            raise PathError(path, LOG_KEY, "its folder does not exist (the log is opened there, "
                            "not made); expected a file in an existing folder")  # fmt: skip
        output_file(path, LOG_KEY, "expected a log file to write")
    except UssSlamError as error:
        release_run_folders()
        raise RefusedRunFolder(error) from None


def _hydra_config_set(config: Any) -> None:
    """Hydra's own config (``${hydra:runtime.cwd}``, ``${hydra:job.name}``) readable while the
    run's folders are checked: Hydra sets it only as the job starts, after these callbacks, so
    an ``out_dir=${hydra:runtime.cwd}/o`` would otherwise fail to resolve here."""
    from hydra.conf import HydraConf
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import DictConfig, OmegaConf

    if isinstance(config, DictConfig) and "hydra" in config:
        node = OmegaConf.get_type(config, "hydra")
        if isinstance(node, type) and issubclass(node, HydraConf):  # a config Hydra composed
            HydraConfig.instance().set_config(config)


def _is_null(config: Any, key: str) -> bool:
    """Whether ``key`` of ``config`` is null (not an interpolation that fails)."""
    from omegaconf import OmegaConf

    parent_key, _, last = key.rpartition(".")
    try:
        parent = OmegaConf.select(config, parent_key) if parent_key else config
        if parent is None or OmegaConf.is_interpolation(parent, last):
            return False  # an interpolation that fails is its own error
        return last in parent and parent[last] is None
    except Exception:  # noqa: BLE001 (no such key: not null)
        return False


class RunFolderCheck:
    """Hydra callback (``_target_`` this class, ``prog`` the app, ``key`` the setting the error
    line names: ``hydra.run.dir``, or ``out_dir`` where that sets the run folder) that checks
    and locks the run folder when a single run starts. Multirun job folders are Hydra's own
    fresh sweep folders and are not checked. Under DDP, the processes Lightning starts for the
    other ranks (``LOCAL_RANK`` > 0) run in the folder rank 0 holds: they do not lock it."""

    def __init__(
        self,
        prog: str,
        key: str = "hydra.run.dir",
        lock: bool = True,
        outputs: dict[str, str | None] | None = None,
        inputs: list[str] | None = None,
        key_only: bool = False,
    ) -> None:
        self.prog = prog
        self.key_only = key_only
        """The app writes into Hydra's run folder, which ``key`` sets: ``hydra.run.dir`` set
        to another folder is refused (the outputs would go there, not where ``key`` says)."""
        self.key = key
        self.lock = lock
        self.outputs = dict(outputs or {})
        """The app's own output folders checked first, before its run folder (``out_dir:
        out``: the key ``out_dir``, unless the key ``out`` is set): a problem both share (a
        read-only parent, a umask) is named by the key the user set for the outputs."""
        self.inputs = list(inputs or [])
        """Keys of the app's input folders (``sequence.path``; a section such as ``data``: every
        ``root`` / ``roots`` in it): an output folder that is one of them is refused, as
        ``uss-eval --out`` a ``--sequence`` is (the outputs would be written among the
        inputs)."""

    def _input_folders(self, config: Any) -> list[tuple[str | None, str]]:
        from omegaconf import OmegaConf

        from uss_slam.core.paths import config_roots

        found: list[tuple[str | None, str]] = []
        for key in self.inputs:
            try:
                value = OmegaConf.select(config, key)
                if OmegaConf.is_config(value):
                    value = OmegaConf.to_container(value, resolve=True)
            except Exception:  # noqa: BLE001 (an interpolation that fails: its own error later)
                continue
            if isinstance(value, dict | list):
                found.extend(config_roots(value, key))
            elif isinstance(value, str) and value:
                found.append((key, value))
        return found

    def _check_outputs(self, config: Any) -> None:
        from omegaconf import OmegaConf

        from uss_slam.core.paths import output_folder

        for key, unless in self.outputs.items():
            if unless is not None and OmegaConf.select(config, unless) is not None:
                continue
            value = OmegaConf.select(config, key)
            if value is not None and str(value) != str(config.hydra.run.dir):
                output_folder(str(value), key, inputs=self._input_folders(config))

    def on_run_start(self, config: Any, **kwargs: Any) -> None:
        _hydra_config_set(config)
        try:
            folder = str(config.hydra.run.dir)
        except Exception as error:  # an interpolation that cannot be resolved (${nope})
            if type(error).__module__.split(".")[0] != "omegaconf":
                raise
            text = str(getattr(error, "msg", "") or error).strip().splitlines()
            line = f"{self.key}: {text[0] if text else error}"
            if _is_null(config, self.key):  # out_dir=null: the run folder's ${out_dir}
                line = f"{self.key}: expected a folder to write into, got null"
            raise RefusedRunFolder(UssSlamError(line)) from None
        self._one_folder(config, folder, "hydra.run.dir")
        before = _remembered(Path(folder).absolute())  # before the lock makes its parents
        self._own(config, folder, self.key)  # before Hydra opens its log file in it
        _log_file(config, folder)
        if before is not None:
            _started.append(before)

    def _one_folder(self, config: Any, folder: str, hydras: str) -> None:
        """See :attr:`key_only` (``hydras``: Hydra's key of ``folder``, ``hydra.run.dir`` or
        ``hydra.sweep.dir``)."""
        from omegaconf import OmegaConf

        from uss_slam.core.hydra_lines import typed_overrides
        from uss_slam.core.paths import where

        if not self.key_only or self.key == "hydra.run.dir":
            return
        task = typed_overrides(config.hydra)
        if self.key not in {o.split("=", 1)[0].lstrip("+~") for o in task}:
            return  # (Hydra's key alone says where the user wants the outputs)
        named = OmegaConf.select(config, self.key, default=None, throw_on_resolution_failure=False)
        if named is not None and os.path.realpath(str(named)) != os.path.realpath(folder):
            kind = "run" if hydras == "hydra.run.dir" else "sweep"
            raise RefusedRunFolder(UssSlamError(
                f"{where(folder, hydras)}: is not {where(str(named), self.key)}, which sets the "
                f"{kind} folder of {self.prog}; expected {self.key} alone"))  # fmt: skip

    def _own(self, config: Any, folder: str, key: str) -> None:
        """Check ``folder`` (named ``key``) and the app's outputs, and lock it; else
        :class:`RefusedRunFolder`."""
        from uss_slam.core.files import check_output_owner, output_lock
        from uss_slam.core.paths import output_folder

        try:
            self._check_outputs(config)
            output_folder(folder, key, inputs=self._input_folders(config))
            if self.lock and os.environ.get("LOCAL_RANK", "0") == "0":
                held = output_lock(folder, key)
                held.__enter__()
                _held.append(held)
            check_output_owner(folder, self.prog, key)
        except UssSlamError as error:
            release_run_folders()
            raise RefusedRunFolder(error) from None

    def on_run_end(self, config: Any, **kwargs: Any) -> None:
        release_run_folders()

    # Hydra calls every hook of a callback (its base class would import Hydra here)
    def on_multirun_start(self, config: Any, **kwargs: Any) -> None:
        """A multirun's sweep folder is checked and locked as a run folder is (an input
        folder, another tool's, one that cannot be written), before Hydra writes into it;
        named by the app's key where that sets it (``out_dir``), else ``hydra.sweep.dir``. A
        sweep with no value is refused first (Hydra would start no job and exit 0)."""
        from omegaconf import OmegaConf

        from uss_slam.core import job_records
        from uss_slam.core.hydra_lines import empty_sweep_line

        _hydra_config_set(config)
        empty = empty_sweep_line(config)
        if empty is not None:
            raise RefusedRunFolder(UssSlamError(empty))
        sweep = str(config.hydra.sweep.dir)
        job_records.sweep_dir = sweep  # where jobs in processes report
        self._one_folder(config, sweep, "hydra.sweep.dir")
        named = OmegaConf.select(config, self.key, default=None, throw_on_resolution_failure=False)
        self._own(config, sweep, self.key if str(named) == sweep else "hydra.sweep.dir")

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        pass

    def on_job_start(self, config: Any, **kwargs: Any) -> None:
        pass

    def on_job_end(self, config: Any, job_return: Any, **kwargs: Any) -> None:
        pass

    def on_compose_config(self, config: Any, **kwargs: Any) -> None:
        pass

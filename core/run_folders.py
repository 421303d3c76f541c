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

import os
from contextlib import AbstractContextManager
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


def release_run_folders() -> None:
    """Release every run-folder lock this process took (last taken first)."""
    while _held:
        _held.pop().__exit__(None, None, None)


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
    ) -> None:
        self.prog = prog
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
        from uss_slam.core.files import check_output_owner, output_lock
        from uss_slam.core.paths import output_folder

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
        try:
            self._check_outputs(config)
            # before Hydra opens its log file in it
            output_folder(folder, self.key, inputs=self._input_folders(config))
            if self.lock and os.environ.get("LOCAL_RANK", "0") == "0":
                held = output_lock(folder, self.key)
                held.__enter__()
                _held.append(held)
            check_output_owner(folder, self.prog, self.key)
        except UssSlamError as error:
            release_run_folders()
            raise RefusedRunFolder(error) from None

    def on_run_end(self, config: Any, **kwargs: Any) -> None:
        release_run_folders()

    # Hydra calls every hook of a callback (its base class would import Hydra here)
    def on_multirun_start(self, config: Any, **kwargs: Any) -> None:
        from uss_slam.core import job_records

        job_records.sweep_dir = str(config.hydra.sweep.dir)  # where jobs in processes report

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        pass

    def on_job_start(self, config: Any, **kwargs: Any) -> None:
        pass

    def on_job_end(self, config: Any, job_return: Any, **kwargs: Any) -> None:
        pass

    def on_compose_config(self, config: Any, **kwargs: Any) -> None:
        pass

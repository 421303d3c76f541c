"""The jobs of a Hydra multirun that a launcher runs in processes of its own
(``hydra/launcher=joblib``, ``submitit_local``), told to the process that started them.

In such a process the console script's report (:class:`uss_slam.core.cli.JobReport`) is not
there: a job that failed with a user error would end its worker process, and joblib would then
stop every other job and the multirun as a whole. Instead each job writes a record of itself
into ``<hydra.sweep.dir>/.uss-jobs/<num>.json`` (its overrides, and its error line if it
failed), returns as a finished job, and the console script reads the records when the multirun
ends (:func:`collect`), lists the failed jobs and exits with 1, as with the default launcher.
The records are removed once read.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

FOLDER = ".uss-jobs"

sweep_dir: str | None = None
"""The sweep folder of the multirun in progress in this process (set when it starts)."""


def record(num: int, overrides: tuple[str, ...], line: str | None = None) -> None:
    """Write job ``num``'s record (from inside the job: its sweep folder is Hydra's)."""
    from hydra.core.hydra_config import HydraConfig

    folder = Path(str(HydraConfig.get().sweep.dir)) / FOLDER
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{num}.json"
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(
        json.dumps({"num": num, "overrides": list(overrides), "line": line}), encoding="utf-8"
    )
    os.replace(tmp, path)


def collect() -> list[dict[str, object]]:
    """The records of the jobs of the multirun that ended (by job number), removed."""
    global sweep_dir
    if sweep_dir is None:
        return []
    folder, sweep_dir = Path(sweep_dir) / FOLDER, None
    found = []
    for path in folder.glob("*.json") if folder.is_dir() else ():
        try:
            found.append(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError):
            continue
    shutil.rmtree(folder, ignore_errors=True)
    return sorted(found, key=lambda r: int(r["num"]))  # type: ignore[call-overload]

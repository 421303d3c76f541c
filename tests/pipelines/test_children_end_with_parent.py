"""kill -9 of a driver: the processes it started end with it (Linux: ``PR_SET_PDEATHSIG``).

uss-experiments' multirun child (its job runner) and the worker processes that render the demo's
and the experiments' data must not keep running, and writing, after their parent was killed:
a rerun would write the same folders. Each test starts a small driver that runs the real
launcher / pool with children that only sleep and report their pids, kills the driver with
SIGKILL and waits for the children to be gone.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from uss_slam.core.files import output_lock

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux's")


def _gone(pid: int) -> bool:
    """True when ``pid`` has ended (a zombie waiting for its new parent to reap it counts)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state in ("Z", "X")


def _pids(path: Path, count: int, driver: subprocess.Popen, timeout: float = 60) -> list[int]:
    """The ``count`` child pids the children wrote to ``path`` (one per line)."""
    deadline = time.monotonic() + timeout
    while True:
        lines = path.read_text().split() if path.is_file() else []
        if len(lines) >= count:
            return [int(line) for line in lines[:count]]
        assert driver.poll() is None, driver.communicate()
        assert time.monotonic() < deadline, "the children did not start"
        time.sleep(0.02)


def _kill_and_wait(driver: subprocess.Popen, children: list[int], within: float = 5.0) -> None:
    try:
        assert not any(_gone(pid) for pid in children)  # running before the kill
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait(timeout=30)
        deadline = time.monotonic() + within
        while not all(_gone(pid) for pid in children):
            assert time.monotonic() < deadline, [p for p in children if not _gone(p)]
            time.sleep(0.02)
    finally:
        for pid in children:  # whatever happens, leave nothing running
            if not _gone(pid):
                os.kill(pid, signal.SIGKILL)


def test_the_experiments_job_runner_ends_with_a_killed_uss_experiments(tmp_path: Path) -> None:
    """The launcher's multirun child (here a process that sleeps) ends within seconds of a
    kill -9 of the process that launched it."""
    pids = tmp_path / "pids"
    child = (
        f"import os, time; open({str(pids)!r}, 'a').write(f'{{os.getpid()}}\\n'); time.sleep(120)"
    )
    driver_code = textwrap.dedent(f"""
        import json, sys, types
        from pathlib import Path
        from uss_slam.pipelines.experiments.launch import _run_and_watch

        out = Path({str(tmp_path / "exp")!r})
        (out / "jobs").mkdir(parents=True)
        (out / "jobs" / "slam.json").write_text(json.dumps({{"cells": {{}}}}))
        exp = types.SimpleNamespace(out=out)
        _run_and_watch(exp, "slam", [sys.executable, "-c", {child!r}], out / "log", [], every=0.2)
    """)
    driver = subprocess.Popen([sys.executable, "-c", driver_code], stderr=subprocess.PIPE)
    _kill_and_wait(driver, _pids(pids, 1, driver))


def test_the_demo_data_workers_end_with_a_killed_uss_demo(tmp_path: Path) -> None:
    """The two worker processes rendering the demo data set end within seconds of a kill -9 of
    the demo; the data folder's lock is free once they are gone (a rerun is never raced)."""
    pids = tmp_path / "pids"
    out = tmp_path / "demo" / "data"
    driver_code = textwrap.dedent(f"""
        import os, time
        from pathlib import Path
        from uss_slam.pipelines import synthetic_data

        def sleeper(out, size, progress=False):
            with open({str(pids)!r}, "a") as file:
                file.write(f"{{os.getpid()}}\\n")
            time.sleep(120)

        def tasks(tmp, spec):
            return [(name, sleeper, {{"out": tmp / name, "size": (8, 8)}}) for name in "ab"]

        synthetic_data._tasks = tasks  # forked workers see it too
        synthetic_data.render_demo_data(Path({str(out)!r}), synthetic_data.DemoData(), workers=2,
                                   progress=False)
    """)
    driver = subprocess.Popen([sys.executable, "-c", driver_code], stderr=subprocess.PIPE)
    _kill_and_wait(driver, _pids(pids, 2, driver))
    deadline = time.monotonic() + 5
    while True:
        try:
            with output_lock(out):
                break
        except Exception:
            assert time.monotonic() < deadline
            time.sleep(0.05)


def _jobs_app(pids: Path) -> str:
    """A Hydra app running ``jobs.run_cell`` on jobs of kind ``sleep`` (each writes its pid to
    ``pids`` and sleeps); ``main`` is defined in the app, so that launchers send its code."""
    return textwrap.dedent(f"""
        import os, sys, time
        from pathlib import Path
        import hydra
        from uss_slam.pipelines.experiments import jobs

        def sleeper(folder, spec):
            with open({str(pids)!r}, "a") as file:
                file.write(f"{{os.getpid()}}\\n")
            time.sleep(120)
            return {{}}

        @hydra.main(version_base="1.3", config_path=None, config_name=None)
        def main(cfg):
            jobs.KINDS["sleep"] = sleeper
            return jobs.run_cell(Path(cfg.plan), Path(cfg.out), str(cfg.cell))
    """)


def test_joblib_workers_end_with_a_killed_job_runner(tmp_path: Path) -> None:
    """With ``launcher=joblib`` the jobs run in joblib's worker processes, which would finish
    the job they are on after the job runner was killed; each job ends with it instead."""
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    pids = tmp_path / "pids"
    out = tmp_path / "exp"
    out.mkdir()
    plan = out / "plan.json"
    plan.write_text('{"cells": {"a": {"kind": "sleep", "key": "a"}, "b": {"kind": "sleep", '
                    '"key": "b"}}}')  # fmt: skip
    sweep = tmp_path / "multirun"
    driver_code = _jobs_app(pids) + textwrap.dedent(f"""
        sys.argv = [sys.argv[0], "-m", "+plan={plan}", "+out={out}", "+cell=a,b",
                    "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                    "hydra.sweep.dir={sweep}"]
        main()
    """)
    driver = subprocess.Popen([sys.executable, "-c", driver_code], stderr=subprocess.PIPE)
    children = _pids(pids, 2, driver)
    assert driver.pid not in children  # they run in joblib's workers, not in the job runner
    _kill_and_wait(driver, children)
    assert not (out / "a" / "result.json").exists() and not (out / "b" / "result.json").exists()


def test_submitit_local_jobs_end_with_a_killed_uss_experiments(tmp_path: Path) -> None:
    """submitit's local executor runs each job under a process of its own, which outlives a
    killed job runner; the jobs watch the process that launched the multirun and end with it."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    pids = tmp_path / "pids"
    app = tmp_path / "app.py"
    app.write_text(_jobs_app(pids) + '\nif __name__ == "__main__":\n    main()\n')
    out = tmp_path / "exp"
    out.mkdir()
    plan = out / "plan.json"
    plan.write_text('{"cells": {"a": {"kind": "sleep", "key": "a"}}}')
    sweep = tmp_path / "multirun"
    command = [sys.executable, str(app), "-m", f"+plan={plan}", f"+out={out}", "+cell=a",
               "hydra/launcher=submitit_local", f"hydra.sweep.dir={sweep}"]  # fmt: skip
    # the driver stands in for uss-experiments: the multirun as launch.py starts it
    driver_code = textwrap.dedent(f"""
        import os, subprocess
        from uss_slam.core.processes import ends_with_parent, watched_by_children
        proc = subprocess.Popen({command!r}, preexec_fn=ends_with_parent(),
                                env={{**os.environ, **watched_by_children()}})
        proc.wait()
    """)
    driver = subprocess.Popen([sys.executable, "-c", driver_code], stderr=subprocess.PIPE)
    children = _pids(pids, 1, driver, timeout=120)
    _kill_and_wait(driver, children)
    assert not (out / "a" / "result.json").exists()

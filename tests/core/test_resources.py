"""Bounded work: the memory available (/proc/meminfo, a cgroup limit, ulimit -v) and the one
line a run whose estimate exceeds it prints before any work (core/resources.py)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from uss_slam.core import resources
from uss_slam.core.errors import UssSlamError


def test_the_line_names_the_settings_the_need_and_what_limits_it(monkeypatch) -> None:
    monkeypatch.delenv(resources.MEMORY_OVERRIDE, raising=False)
    monkeypatch.setattr(resources, "available_memory", lambda: (2_000_000_000, "ulimit -v"))
    with pytest.raises(UssSlamError) as info:
        resources.check_memory(5_500_000_000, "--size=4096x4096", "rendering a frame", "--size")
    assert str(info.value) == (
        "--size=4096x4096: rendering a frame needs about 5.5 GB of memory; this machine has "
        "2.0 GB available (ulimit -v); lower --size (or set USS_SLAM_NO_MEMORY_CHECK=1 to try "
        "anyway)"
    )
    resources.check_memory(1_000_000_000, "k", "w", "k")  # fits: nothing
    monkeypatch.setenv(resources.MEMORY_OVERRIDE, "1")
    resources.check_memory(5_500_000_000, "k", "w", "k")  # the user's call


def test_jobs_run_at_once_by_the_launcher_each_count(monkeypatch) -> None:
    """Inside a joblib multirun (uss-experiments' jobs, ``uss-slam -m`` with
    ``hydra/launcher=joblib``) each of ``hydra.launcher.n_jobs`` jobs at once needs as much."""
    monkeypatch.delenv(resources.MEMORY_OVERRIDE, raising=False)
    monkeypatch.setattr(resources, "available_memory", lambda: (2_000_000_000, "ulimit -v"))
    resources.check_memory(1_500_000_000, "k=1", "w", "k")  # one run: fits
    monkeypatch.setattr(resources, "jobs_at_once", lambda: 2)
    with pytest.raises(UssSlamError) as info:
        resources.check_memory(1_500_000_000, "k=1", "w", "k")
    assert str(info.value) == (
        "k=1, hydra.launcher.n_jobs (2 jobs at once): each of 2 jobs, w, needs about 1.5 GB of "
        "memory (3.0 GB in all); this machine has 2.0 GB available (ulimit -v); lower k or "
        "hydra.launcher.n_jobs (or set USS_SLAM_NO_MEMORY_CHECK=1 to try anyway)"
    )


def test_jobs_at_once_reads_the_joblib_launcher(monkeypatch) -> None:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    monkeypatch.setattr(HydraConfig, "initialized", staticmethod(lambda: False))
    assert resources.jobs_at_once() == 1  # not a Hydra app
    for n_jobs, at_once in ((3, 3), (-1, os.cpu_count()), (None, 1)):
        cfg = OmegaConf.create({"mode": RunMode.MULTIRUN, "launcher": {"n_jobs": n_jobs}})
        monkeypatch.setattr(HydraConfig, "initialized", staticmethod(lambda: True))
        monkeypatch.setattr(HydraConfig, "get", staticmethod(lambda cfg=cfg: cfg))
        assert resources.jobs_at_once() == at_once


def test_a_cgroup_limit_counts_from_the_process_group_up(tmp_path: Path) -> None:
    group = tmp_path / "memory" / "jobs" / "job1"
    group.mkdir(parents=True)
    (group / "memory.limit_in_bytes").write_text("9223372036854771712\n")  # v1: no limit here
    (group / "memory.usage_in_bytes").write_text("100\n")
    (tmp_path / "memory" / "jobs" / "memory.limit_in_bytes").write_text("1000\n")
    (tmp_path / "memory" / "jobs" / "memory.usage_in_bytes").write_text("400\n")
    table = tmp_path / "cgroup"
    table.write_text("4:memory:/jobs/job1\n0::/\n")
    dirs = resources._cgroup_dirs(tmp_path, table)
    assert dirs[:3] == [group, group.parent, tmp_path / "memory"]
    v2 = tmp_path / "v2"
    (v2 / "slice").mkdir(parents=True)
    (v2 / "slice" / "memory.max").write_text("5000\n")
    (v2 / "slice" / "memory.current").write_text("1000\n")
    table.write_text("0::/slice\n")
    assert resources._cgroup_dirs(v2, table)[0] == v2 / "slice"


def test_ulimit_v_is_what_is_left() -> None:
    """Under ``ulimit -v`` the memory available is at most the limit less what is mapped."""
    code = (
        "import resource; resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, resource.RLIM_INFINITY));"
        "from uss_slam.core.resources import available_memory; n, w = available_memory();"
        "print(n, w)"
    )  # fmt: skip
    if resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY:
        pytest.skip("this process already runs under ulimit -v")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    left, where = out.stdout.split(maxsplit=1)
    assert int(left) < 3 * 2**30
    assert where.strip() in (
        "ulimit -v",
        "MemAvailable of /proc/meminfo",
        "its cgroup's memory limit",
    )


def test_uss_synth_refuses_a_frame_the_memory_cannot_hold(monkeypatch, tmp_path, capsys) -> None:
    from uss_slam.synthetic import cli

    monkeypatch.delenv(resources.MEMORY_OVERRIDE, raising=False)
    monkeypatch.setattr(resources, "available_memory", lambda: (500_000_000, "ulimit -v"))
    code = cli.main(["voc", "--images", "1", "--size", "4096x4096", "--out", str(tmp_path / "v")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1, err
    assert err[0].startswith("uss-synth: error: --size=4096x4096: rendering a frame needs about")
    assert not (tmp_path / "v").exists()


def test_a_stride_that_keeps_only_the_first_frame_is_refused() -> None:
    from uss_slam.core.ranges import check_stride

    check_stride(5, 30, "--stride", "seq")  # six frames: fine
    check_stride(1, 1, "--stride", "seq")  # one frame, no stride: fine
    with pytest.raises(UssSlamError, match="--stride 30: seq has 30 frames, so it would keep only"):
        check_stride(30, 30, "--stride", "seq")

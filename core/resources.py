"""Bounded work: the memory this process may still take, and the one line a run prints before
any work when its settings would need more (torch-free, floor 0).

The memory available is the least of what the machine, the control group and the process's
own limit leave:

- ``MemAvailable`` of ``/proc/meminfo`` (what the kernel can hand out without swapping);
- a cgroup limit when one is set (v2 ``memory.max`` − ``memory.current``, v1
  ``memory.limit_in_bytes`` − ``memory.usage_in_bytes``: a container's or a SLURM job's);
- ``ulimit -v`` (``RLIMIT_AS``) − the address space the process already maps.

A run's need is an estimate from its settings (``train/memory.py`` for a training, the frame
size for ``uss-synth`` and ``uss-slam``); it is compared before any work, and a need above
what is available is one line naming the settings: ``data.batch_size=64,
data.source.transform.crop_size=1025, model/net=...: training needs about 210 GB of memory;
this machine has 12.1 GB available (MemAvailable); lower ...``.
"""

from __future__ import annotations

import os
import resource
from pathlib import Path

from uss_slam.core.errors import UssSlamError

CGROUP = Path("/sys/fs/cgroup")
"""Where the control groups are mounted (Linux)."""
MEMINFO = Path("/proc/meminfo")


def _meminfo(name: str, meminfo: Path = MEMINFO) -> int | None:
    """The ``name`` row of ``/proc/meminfo`` in bytes (None where there is none)."""
    try:
        for line in meminfo.read_text(encoding="utf-8").splitlines():
            key, _, rest = line.partition(":")
            if key == name:
                return int(rest.split()[0]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _read_int(path: Path) -> int | None:
    """An integer file of the cgroup tree (None: absent, unreadable or ``max``)."""
    try:
        text = path.read_text(encoding="utf-8").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _cgroup_dirs(root: Path = CGROUP, table: Path = Path("/proc/self/cgroup")) -> list[Path]:
    """The memory-controller folders of this process's control group and of its ancestors
    (v2: ``0::/path``; v1: ``N:memory:/path``), the mount's root last."""
    dirs: list[Path] = []
    try:
        lines = table.read_text(encoding="utf-8").splitlines()
    except OSError:
        lines = []
    for line in lines:
        _, controllers, path = line.split(":", 2)
        base = (
            root
            if controllers == ""
            else root / "memory"
            if "memory" in controllers.split(",")
            else None
        )
        if base is None:
            continue
        here = base / path.lstrip("/")
        while here != base and base in here.parents:
            dirs.append(here)
            here = here.parent
        dirs.append(base)
    return dirs or [root, root / "memory"]


def _cgroup_left(root: Path = CGROUP) -> int | None:
    """Bytes the process's control group (or an ancestor's limit) may still take (None: no
    limit set: a container's, a SLURM job's or a systemd slice's)."""
    left: list[int] = []
    for folder in _cgroup_dirs(root):
        for limit, usage in (("memory.max", "memory.current"),
                             ("memory.limit_in_bytes", "memory.usage_in_bytes")):  # fmt: skip
            cap, used = _read_int(folder / limit), _read_int(folder / usage)
            if cap is not None and cap < 1 << 60 and used is not None:  # v1's "none": ~2**63
                left.append(max(0, cap - used))
    return min(left, default=None)


def _address_space_left() -> int | None:
    """Bytes ``ulimit -v`` leaves above what the process maps already (None: unlimited)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    mapped = _meminfo_of_self("VmSize") or 0
    return max(0, soft - mapped)


def _meminfo_of_self(name: str) -> int | None:
    """A ``Vm*`` row of ``/proc/self/status`` in bytes."""
    return _meminfo(name, Path("/proc/self/status"))


def held_bytes() -> int:
    """Bytes this process holds now (``VmRSS`` of ``/proc/self/status``; 0 where unknown)."""
    return _meminfo_of_self("VmRSS") or 0


def estimate_line(need: int) -> str:
    """The log line of a memory estimate of ``need`` bytes beside what this process holds now
    (the form ``studies/memory_peaks.py`` reads back)."""
    jobs = jobs_at_once()
    each = f" (each of {jobs} jobs at once)" if jobs > 1 else ""
    return f"memory estimate: {need} bytes beyond the {held_bytes()} held now{each}"


def available_memory() -> tuple[int | None, str]:
    """``(bytes, where)``: the least memory left by the machine, the cgroup and ``ulimit -v``,
    and which of them it is (None, "": nothing known, e.g. not Linux)."""
    found = [
        (value, where)
        for value, where in (
            (_meminfo("MemAvailable"), "MemAvailable of /proc/meminfo"),
            (_cgroup_left(), "its cgroup's memory limit"),
            (_address_space_left(), "ulimit -v"),
        )
        if value is not None
    ]
    if not found:
        return None, ""
    return min(found)


def gigabytes(n: float) -> str:
    """``n`` bytes as ``'12.1 GB'`` (``'850 MB'`` below one GB)."""
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{max(n, 0) / 1e6:.0f} MB"


MEMORY_OVERRIDE = "USS_SLAM_NO_MEMORY_CHECK"
"""Set (to anything non-empty) to skip the check: an estimate is an estimate, and a machine with
swap or memory overcommit may still run what it refuses."""


def jobs_at_once() -> int:
    """How many jobs of this Hydra multirun its launcher runs at once: ``hydra.launcher.n_jobs``
    of the joblib launcher (``-1``: one per CPU, ``-2``: all but one, as joblib counts), else 1
    (one run, or the basic launcher's jobs one after another)."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode
    except ImportError:
        return 1
    if not HydraConfig.initialized() or HydraConfig.get().mode != RunMode.MULTIRUN:
        return 1
    n_jobs = HydraConfig.get().launcher.get("n_jobs")
    if not isinstance(n_jobs, int) or isinstance(n_jobs, bool) or n_jobs == 0:
        return 1
    return max(1, n_jobs if n_jobs > 0 else (os.cpu_count() or 1) + 1 + n_jobs)


def check_memory(need: int, settings: str, what: str, lower: str) -> None:
    """Raise the one line when ``need`` bytes (the estimate for ``what``, from ``settings``,
    e.g. ``'data.batch_size=64, crop 1025 px'``) exceed the memory available; ``lower`` says
    which settings to lower. Inside a multirun whose launcher runs jobs in parallel, each of
    :func:`jobs_at_once` jobs is counted with the same need. Does nothing when the memory
    available is unknown or :data:`MEMORY_OVERRIDE` is set."""
    if os.environ.get(MEMORY_OVERRIDE):
        return
    available, where = available_memory()
    jobs = jobs_at_once()
    if available is None or need * jobs <= available:
        return
    if jobs > 1:
        settings += f", hydra.launcher.n_jobs ({jobs} jobs at once)"
        what = f"each of {jobs} jobs, {what},"
        lower += " or hydra.launcher.n_jobs"
    raise UssSlamError(
        f"{settings}: {what} needs about {gigabytes(need)} of memory"
        + (f" ({gigabytes(need * jobs)} in all)" if jobs > 1 else "")
        + f"; this machine has {gigabytes(available)} available ({where}); lower {lower} (or "
        f"set {MEMORY_OVERRIDE}=1 to try anyway)"
    )

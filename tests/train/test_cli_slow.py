"""`uss-train` as users run it (subprocesses): a Hydra multirun sweep and DDP on CPU."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml
from shared_helpers import data_overrides
from train_helpers import RENDEZVOUS


def _uss_train(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "uss-train"
    result = subprocess.run([str(exe), *args], cwd=cwd, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result


@pytest.mark.slow
def test_multirun_sweeps_discriminator_depth(uda_data: dict[str, Path], tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    _uss_train(
        "-m",
        "experiment=ci",
        "model.method.discriminator.n_layers=4,5",
        *data_overrides(uda_data),
        "logger=none",
        "model.max_iters=2",
        f"hydra.sweep.dir={sweep}",
        cwd=tmp_path,
    )
    for job, n_layers in (("0", 4), ("1", 5)):
        overrides = yaml.safe_load((sweep / job / ".hydra" / "overrides.yaml").read_text())
        assert f"model.method.discriminator.n_layers={n_layers}" in overrides
        state = torch.load(sweep / job / "checkpoints" / "last.ckpt", weights_only=True)
        convs = [
            k
            for k in state["state_dict"]
            if k.startswith("method.d_main.") and k.endswith("weight")
        ]
        assert len(convs) == n_layers
        assert state["iteration"] == 2
    assert (sweep / "multirun.yaml").is_file()


def _uss_train_ddp(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``uss-train`` with DDP as a user starts it: none of :data:`RENDEZVOUS` set (a test run
    in this process before may have left Lightning's in ``os.environ``, naming a port this
    process still listens on: EADDRINUSE)."""
    exe = Path(sys.executable).parent / "uss-train"
    env = {k: v for k, v in os.environ.items() if k not in RENDEZVOUS}
    result = subprocess.run(
        [str(exe), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=900
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result


@pytest.mark.slow
def test_ddp_on_cpu_keeps_replicas_identical(uda_data: dict[str, Path], tmp_path: Path) -> None:
    run = tmp_path / "run"
    _uss_train_ddp(
        "experiment=ci",
        "trainer=ddp_cpu",
        *data_overrides(uda_data),
        "logger=none",
        f"hydra.run.dir={run}",
        cwd=tmp_path,
    )
    record = json.loads((run / "replicas.json").read_text())
    assert record["iteration"] == 4
    assert len(record["parameters"]) == 2 and len(set(record["parameters"])) == 1
    assert len(set(record["buffers"])) == 1
    state = torch.load(run / "checkpoints" / "last.ckpt", weights_only=True)
    assert state["iteration"] == 4


@pytest.mark.slow
def test_a_training_runs_with_every_warning_an_error(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    """``PYTHONWARNINGS=error``: no warning in a normal run stops it (Lightning's own were a
    traceback at the first batch), and none of the silenced ones is printed."""
    exe = Path(sys.executable).parent / "uss-train"
    env = {**os.environ, "PYTHONWARNINGS": "error"}
    run = tmp_path / "run"
    args = ["experiment=ci", *data_overrides(uda_data), "logger=none", "model.max_iters=2"]
    result = subprocess.run(
        [str(exe), *args, f"hydra.run.dir={run}"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    assert (run / "checkpoints" / "last.ckpt").is_file()
    assert "LeafSpec" not in result.stderr and "in eval mode" not in result.stderr

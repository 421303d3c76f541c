"""The CUDA paths of training: the small model on ``trainer=gpu`` (device placement, pinned
batches), automatic mixed precision (``trainer.precision=bf16-mixed`` / ``16-mixed``) and DDP
over NCCL (``trainer=ddp``). Marked ``gpu``: skipped where ``torch.cuda.is_available()`` is false
(``tests/conftest.py``)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import torch
from hydra.utils import instantiate
from lightning.pytorch import Callback, LightningModule, Trainer
from shared_helpers import compose_train, data_overrides
from torch import nn

pytestmark = pytest.mark.gpu

AUTOCAST_DTYPES = {
    "32-true": torch.float32,
    "bf16-mixed": torch.bfloat16,
    "16-mixed": torch.float16,
}


class DeviceProbe(Callback):
    """Where the module's parameters and each training batch are, and the dtype the segmenter's
    last convolution computes in during the training steps."""

    def __init__(self) -> None:
        self.batches: list[tuple[torch.device, torch.device]] = []
        self.parameters: set[torch.device] = set()
        self.conv_dtypes: set[torch.dtype] = set()

    def on_train_start(self, trainer: Trainer, pl_module: LightningModule) -> None:
        last_conv = [m for m in pl_module.segmenter.modules() if isinstance(m, nn.Conv2d)][-1]
        last_conv.register_forward_hook(
            lambda module, inputs, output: (
                self.conv_dtypes.add(output.dtype) if module.training else None
            )
        )

    def on_train_batch_start(
        self, trainer: Trainer, pl_module: LightningModule, batch: Any, batch_idx: int
    ) -> None:
        self.batches.append((batch["source"]["image"].device, batch["target"]["image"].device))
        self.parameters |= {p.device for p in pl_module.parameters()}


def _fit(uda_data: dict[str, Path], tmp_path: Path, *overrides: str) -> tuple[Any, ...]:
    """Two iterations of ``experiment=ci trainer=gpu`` on the synthetic fixture data."""
    cfg = compose_train(
        [
            "experiment=ci",
            "trainer=gpu",
            *data_overrides(uda_data),
            "logger=none",
            "model.max_iters=2",
            "data.iterations_per_epoch=2",
            *overrides,
        ],
        tmp_path / "run",
    )
    datamodule = instantiate(cfg.data)
    model = instantiate(cfg.model)
    probe = DeviceProbe()
    trainer = instantiate(
        cfg.trainer,
        callbacks=[probe],
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
    )
    trainer.fit(model, datamodule=datamodule)
    return cfg, trainer, model, datamodule, probe


def test_small_model_trains_on_the_gpu_with_pinned_batches(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    cfg, trainer, model, datamodule, probe = _fit(uda_data, tmp_path)
    assert model.iteration == 2 and len(probe.batches) == 2
    assert {d.type for pair in probe.batches for d in pair} == {"cuda"}
    assert {d.type for d in probe.parameters} == {"cuda"}
    assert probe.conv_dtypes == {torch.float32}
    # trainer=gpu pins the host batches of every loader
    assert cfg.data.pin_memory is True and datamodule.pin_memory is True
    loaders = [*datamodule.train_dataloader().flattened, datamodule.val_dataloader()]
    assert all(loader.pin_memory for loader in loaders)
    assert all(math.isfinite(float(v)) for v in trainer.callback_metrics.values())


@pytest.mark.parametrize("precision", ["bf16-mixed", "16-mixed"])
def test_mixed_precision_on_the_gpu(
    precision: str, uda_data: dict[str, Path], tmp_path: Path
) -> None:
    if precision == "bf16-mixed" and not torch.cuda.is_bf16_supported():
        pytest.skip("this GPU has no bfloat16")
    _, trainer, model, _, probe = _fit(uda_data, tmp_path, f"trainer.precision={precision}")
    assert model.iteration == 2
    # autocast around the training step: the segmenter's convolutions run in the low precision
    assert probe.conv_dtypes == {AUTOCAST_DTYPES[precision]}
    assert {p.dtype for p in model.parameters()} == {torch.float32}  # weights stay float32
    losses = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("train/")}
    assert "train/loss_seg_src_main" in losses
    assert all(math.isfinite(v) for v in losses.values()), losses


@pytest.mark.slow
@pytest.mark.parametrize("devices", [1, 2])
def test_ddp_with_nccl_on_one_node(devices: int, uda_data: dict[str, Path], tmp_path: Path) -> None:
    """``uss-train trainer=ddp`` as users run it (Lightning starts the other ranks)."""
    if torch.cuda.device_count() < devices:
        pytest.skip(f"needs {devices} GPUs, found {torch.cuda.device_count()}")
    run = tmp_path / "run"
    exe = Path(sys.executable).parent / "uss-train"
    result = subprocess.run(
        [
            str(exe),
            "experiment=ci",
            "trainer=ddp",
            f"trainer.devices={devices}",
            *data_overrides(uda_data),
            "logger=none",
            f"hydra.run.dir={run}",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=900,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-6000:]
    assert "distributed_backend=nccl" in output
    state = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert state["iteration"] == 4
    if devices > 1:  # the replica check compares every rank's weights after training
        record = json.loads((run / "replicas.json").read_text())
        assert record["iteration"] == 4 and len(record["parameters"]) == devices
        assert len(set(record["parameters"])) == 1 and len(set(record["buffers"])) == 1

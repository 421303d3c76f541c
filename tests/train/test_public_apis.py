"""Training code uses public Lightning / torchvision APIs only: when the module logs, how the data
module finds its shard and refuses a distributed sampler, and the transforms' size query."""

from __future__ import annotations

import ast
import os
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import torch
from lightning.pytorch import LightningModule, Trainer
from lightning.pytorch.loggers import TensorBoardLogger
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from torch.utils.data import Dataset
from torchvision import tv_tensors
from train_helpers import RENDEZVOUS, fit_repeated, quiet_trainer

from uss_slam.core.errors import UssSlamError
from uss_slam.datasets.datamodule import UDADataModule
from uss_slam.datasets.transforms import RandomScale
from uss_slam.testing import reference_step as bench

REPO = Path(__file__).resolve().parents[2]

# ----------------------------------------------------------------------------- no private APIs

OWN_FILES = [
    *sorted((REPO / "train").rglob("*.py")),
    REPO / "datasets" / "datamodule.py",
    REPO / "datasets" / "transforms.py",
]


@pytest.mark.parametrize("path", OWN_FILES, ids=lambda p: str(p.relative_to(REPO)))
def test_no_private_library_api(path: Path) -> None:
    """No ``from lib._private import``, no ``trainer._x`` / ``loop._x`` / ``v2._x`` access."""
    tree = ast.parse(path.read_text())
    bad = []
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.ImportFrom)
            and node.module
            and not node.module.startswith("uss_slam")
        ):
            if any(p.startswith("_") and p != "__future__" for p in node.module.split(".")):
                bad.append(f"line {node.lineno}: from {node.module}")
            bad += [
                f"line {node.lineno}: import {a.name}" for a in node.names if a.name.startswith("_")
            ]
        if (
            isinstance(node, ast.Attribute)
            and node.attr.startswith("_")
            and not node.attr.startswith("__")
        ):
            owner = node.value
            name = owner.attr if isinstance(owner, ast.Attribute) else getattr(owner, "id", "")
            if name in {"trainer", "fit_loop", "epoch_loop", "strategy", "v2", "F", "torch"}:
                bad.append(f"line {node.lineno}: {name}.{node.attr}")
    assert not bad, bad


# ----------------------------------------------------------------------------- logging steps


def _module(max_iters: int) -> LightningModule:
    torch.manual_seed(0)
    return bench.build_module("resnet_small", max_iters=max_iters, n_layers=4, ndf=8)


def _fit(
    module: LightningModule,
    iters: int,
    logdir: Path,
    every: int,
    ckpt_path: str | None = None,
    max_epochs: int = 1,
    **trainer_args: Any,
) -> Trainer:
    return fit_repeated(
        module,
        bench.random_batch(33, 1),
        iters,
        ckpt_path=ckpt_path,
        max_epochs=max_epochs,
        logger=TensorBoardLogger(logdir, name="", version=""),
        log_every_n_steps=every,
        **trainer_args,
    )


def _steps(logdir: Path, key: str = "train/loss_seg_src_main") -> list[int]:
    events = EventAccumulator(str(logdir), size_guidance={"scalars": 0})
    events.Reload()
    if key not in events.Tags()["scalars"]:
        return []
    return [p.step for p in events.Scalars(key)]


def test_logging_steps_continue_after_resume(tmp_path: Path) -> None:
    # 2 epochs of 3 iterations, then 2 more epochs resumed from the checkpoint: every 4th batch
    # counted over the whole run (3, 7) and the step that stops training (11).
    module = _module(max_iters=12)
    trainer = _fit(module, 3, tmp_path / "first", every=4, max_epochs=2)
    trainer.save_checkpoint(tmp_path / "mid.ckpt")
    assert _steps(tmp_path / "first") == [3]
    resumed = _module(max_iters=12)
    _fit(resumed, 3, tmp_path / "second", every=4, ckpt_path=str(tmp_path / "mid.ckpt"),
         max_epochs=4)  # fmt: skip
    assert resumed.iteration == 12
    assert _steps(tmp_path / "second") == [7, 11]


def test_fast_dev_run_logs_every_step_and_zero_interval_logs_none(tmp_path: Path) -> None:
    module = _module(max_iters=10)
    _fit(module, 2, tmp_path / "never", every=0)
    assert module.iteration == 2 and _steps(tmp_path / "never") == []
    module = _module(max_iters=10)
    # fast_dev_run swaps the loggers for a dummy but logs every step (its single one here).
    trainer = _fit(module, 3, tmp_path / "dev", every=50, fast_dev_run=True)
    assert module.iteration == 1
    assert "train/loss_seg_src_main" in trainer.logged_metrics


# ----------------------------------------------------------------------------- data module


class _Samples(Dataset):
    def __init__(self, n: int) -> None:
        self.n = n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        return {"image": torch.full((3, 4, 4), float(index)), "label": torch.zeros(4, 4).long()}


class _Consumer(LightningModule):
    def __init__(self) -> None:
        super().__init__()
        self.weight = torch.nn.Parameter(torch.zeros(()))
        self.seen: list[float] = []

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        self.seen.append(float(batch["source"]["image"][0, 0, 0, 0]))
        return self.weight * batch["source"]["image"].mean()

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.parameters(), lr=0.1)


def _datamodule() -> UDADataModule:
    return UDADataModule(_Samples(10), _Samples(7), batch_size=2, iterations_per_epoch=3)


@pytest.mark.parametrize(
    ("kwargs", "shard"), [(None, (0, 1)), ({"num_replicas": 4, "rank": 3}, (3, 4))]
)
def test_streams_shard_by_the_distributed_sampler_arguments(
    kwargs: dict | None, shard: tuple[int, int]
) -> None:
    dm = _datamodule()
    dm.trainer = SimpleNamespace(distributed_sampler_kwargs=kwargs)
    loaders = dm.train_dataloader().flattened
    assert [(ld.sampler.rank, ld.sampler.world_size) for ld in loaders] == [shard, shard]


def _trainer(**kwargs: Any) -> Trainer:
    return quiet_trainer(devices=1, **kwargs)


@pytest.fixture
def one_process_group() -> Iterator[None]:
    """Lightning's DDP in this process: its rendezvous variables (``MASTER_PORT``, ...) are
    undone and its process group destroyed afterwards, so that no later ``uss-train`` started
    from this process inherits a port this process still listens on."""
    before = {name: os.environ.get(name) for name in RENDEZVOUS}
    yield
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()
    for name, value in before.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


@pytest.mark.usefixtures("one_process_group")
def test_ddp_with_lightnings_distributed_sampler_is_refused() -> None:
    # One DDP process (gloo) is enough: Lightning wraps the loaders as soon as the strategy is
    # distributed, and a wrapped stream is re-shuffled even with one replica.
    module = _Consumer()
    with pytest.raises(UssSlamError, match="set trainer.use_distributed_sampler=false"):
        _trainer(strategy="ddp", use_distributed_sampler=True).fit(module, datamodule=_datamodule())
    assert module.seen == []
    module = _Consumer()
    _trainer(strategy="ddp", use_distributed_sampler=False).fit(module, datamodule=_datamodule())
    assert len(module.seen) == 3


def test_single_process_streams_are_used_as_they_are() -> None:
    module = _Consumer()
    dm = _datamodule()
    _trainer().fit(module, datamodule=dm)
    reference = [
        float(b["source"]["image"][0, 0, 0, 0]) for b, *_ in _datamodule().train_dataloader()
    ]
    assert module.seen == reference and len(reference) == 3


# ----------------------------------------------------------------------------- transforms


def test_random_scale_sizes_image_and_mask_from_the_sample() -> None:
    torch.manual_seed(0)
    sample = {
        "image": tv_tensors.Image(torch.zeros(3, 5, 7, dtype=torch.uint8)),
        "label": tv_tensors.Mask(torch.zeros(5, 7, dtype=torch.uint8)),
        "name": "x",
    }
    out = RandomScale((2.0, 2.0))(sample)
    assert out["image"].shape == (3, 10, 14) and out["label"].shape == (10, 14)
    assert out["name"] == "x"
    sample["label"] = tv_tensors.Mask(torch.zeros(6, 7, dtype=torch.uint8))
    with pytest.raises(ValueError, match="multiple"):
        RandomScale((2.0, 2.0))(sample)

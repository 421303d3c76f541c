"""The speed and GPU options compose with the shipped configs: mixed precision, DDP over
several GPUs and nodes, compiled networks under DDP, ``trainer=fast_cpu`` (which the benchmark's
``fast`` variant mirrors). Without GPUs, the GPU trainers are checked as composed values, by the
run's own config check and with the model they would train; the Trainer itself is built on CPU."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.utils import instantiate
from lightning.pytorch import Trainer
from lightning.pytorch.strategies import DDPStrategy
from omegaconf import DictConfig, OmegaConf, open_dict

from uss_slam.testing import step_timing as bench
from uss_slam.train.module import AdversarialSegmentation
from uss_slam.train.train import check_config

REPO = Path(__file__).resolve().parents[2]


def _compose(*overrides: str, tmp_path: Path) -> DictConfig:
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(REPO / "configs"), version_base="1.3"):
        cfg = compose("train", overrides=["model/net=deeplab_small", *overrides])
    with open_dict(cfg):
        cfg.paths.output_dir = str(tmp_path / "run")
        cfg.paths.log_dir = str(tmp_path / "logs")
    return cfg


GPU_CASES = [
    ("trainer=gpu", "trainer.precision=bf16-mixed"),
    ("trainer=gpu", "trainer.precision=16-mixed", "model.compile=true"),
    ("trainer=ddp", "trainer.precision=bf16-mixed", "model.compile=true"),
    (
        "trainer=ddp",
        "trainer.devices=8",
        "trainer.num_nodes=4",
        "trainer.precision=16-mixed",
        "data.pin_memory=true",
    ),
    (
        "trainer=ddp",
        "trainer.devices=4",
        "trainer.num_nodes=2",
        "trainer.precision=bf16-mixed",
        "model.compile=true",
        "model.compile_mode=max-autotune-no-cudagraphs",
        "model.optimizer_kernels=fused",
        "model.channels_last=true",
    ),
]


@pytest.mark.parametrize("overrides", GPU_CASES, ids=" ".join)
def test_gpu_options_compose(overrides: tuple[str, ...], tmp_path: Path) -> None:
    cfg = _compose(*overrides, tmp_path=tmp_path)
    check_config(cfg)
    for override in overrides:
        key, _, value = override.partition("=")
        if "." in key:
            assert str(OmegaConf.select(cfg, key)).lower() == value
    model = instantiate(cfg.model)
    assert isinstance(model, AdversarialSegmentation)
    assert model.compile_networks == cfg.model.compile
    if cfg.trainer.get("strategy"):
        assert cfg.trainer.strategy.find_unused_parameters is True  # two backward passes
    # The same trainer on CPU (no GPUs here): Lightning accepts the combination; CPU runs
    # 16-mixed as bf16-mixed.
    trainer_cfg = OmegaConf.to_container(cfg.trainer, resolve=True)
    trainer_cfg.update(accelerator="cpu", logger=False, enable_checkpointing=False)
    trainer: Trainer = instantiate(trainer_cfg)
    assert trainer.precision == "bf16-mixed"
    assert trainer.num_nodes == cfg.trainer.get("num_nodes", 1)
    if "ddp" in overrides[0]:
        assert isinstance(trainer.strategy, DDPStrategy)
        assert trainer.num_devices == cfg.trainer.devices


def test_full_precision_stays_the_default(tmp_path: Path) -> None:
    cfg = _compose(tmp_path=tmp_path)
    assert cfg.trainer.precision == "32-true"
    model = instantiate(cfg.model)
    assert (model.compile_networks, model.channels_last, model.optimizer_kernels) == (
        False,
        False,
        "default",
    )
    demo = instantiate(_compose("experiment=demo", tmp_path=tmp_path).model)
    assert (demo.compile_networks, demo.channels_last) == (False, True)


@pytest.mark.parametrize("experiment", [None, "demo", "ci"])
def test_fast_cpu_sets_what_the_benchmark_measures(experiment: str | None, tmp_path: Path) -> None:
    overrides = ["trainer=fast_cpu"] + ([f"experiment={experiment}"] if experiment else [])
    cfg = _compose(*overrides, tmp_path=tmp_path)
    check_config(cfg)
    assert cfg.trainer.accelerator == "cpu"
    # `auto` resolves per CPU; on one with bfloat16 instructions it is what the benchmark times
    assert cfg.trainer.precision == "auto"
    from uss_slam.train.speed import resolve_precision

    assert resolve_precision("auto", "cpu", {"avx512_bf16"})[0] == bench.FAST_CPU.precision
    model = instantiate(cfg.model)
    for name, value in bench.FAST_CPU.settings.items():
        assert getattr(model, name) == value, name
    # A command-line override still wins over the fast settings.
    slow = instantiate(_compose(*overrides, "model.compile=false", tmp_path=tmp_path).model)
    assert slow.compile_networks is False

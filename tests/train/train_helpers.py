"""Helpers of the training tests: data-path overrides and composing the real config."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, open_dict

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"


def data_overrides(data: dict[str, Path]) -> list[str]:
    return [
        f"data.source.root={data['voc']}",
        f"data.target.roots=[{data['target']}]",
        f"data.val.roots=[{data['val']}]",
        "data.val.stride=1",
    ]


def compose_train(overrides: Sequence[str], output_dir: Path) -> DictConfig:
    """The real ``train.yaml`` composed with ``overrides``; outputs go to ``output_dir``."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=list(overrides), return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(output_dir)
        cfg.hydra.job.num = 0
        cfg.paths.log_dir = str(output_dir.parent / "logs")
    HydraConfig().set_config(cfg)
    return cfg

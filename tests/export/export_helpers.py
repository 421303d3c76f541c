"""Helpers of the export tests: the config tree, a tiny segmenter and a uss-train run folder
holding it."""

from __future__ import annotations

from pathlib import Path

import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.models import DeepLabV2

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
NET_YAML = CONFIG_DIR / "model" / "net" / "deeplab_small.yaml"


def tiny_net(seed: int = 0) -> DeepLabV2:
    """The CI / demo segmenter as configured (``configs/model/net/deeplab_small.yaml``), with
    non-trivial BatchNorm statistics (so the exported graph must carry them)."""
    torch.manual_seed(seed)
    net = instantiate(OmegaConf.load(NET_YAML))
    assert isinstance(net, DeepLabV2) and net.backbone_name == "resnet_small"
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
    return net.eval()


def fake_run(root: Path, net: DeepLabV2, run_name: str = "fake") -> Path:
    """A run folder as uss-train writes it: ``.hydra/config.yaml`` + ``checkpoints/last.ckpt``
    (segmenter and discriminator weights)."""
    (root / ".hydra").mkdir(parents=True)
    (root / "checkpoints").mkdir()
    net_cfg = yaml.safe_load(NET_YAML.read_text())
    config = {"run_name": run_name, "model": {"net": net_cfg}}
    (root / ".hydra" / "config.yaml").write_text(yaml.safe_dump(config))
    state = {f"segmenter.{k}": v for k, v in net.state_dict().items()}
    state["d_main.layers.0.weight"] = torch.ones(2, 4, 4, 4)
    ckpt = root / "checkpoints" / "last.ckpt"
    torch.save(
        {
            "state_dict": state,
            "hyper_parameters": {"class_names": list(CLASS_NAMES)},
            "iteration": 7,
        },
        ckpt,
    )
    return ckpt

"""Helpers of the pipeline tests: a tiny ``uss-train`` run folder and a tiny ONNX segmenter of
the project's contract with known output."""

from __future__ import annotations

from pathlib import Path

import shared_helpers
import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.onnx_contract import SegmenterMetadata
from uss_slam.models import DeepLabV2

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
NET_YAML = CONFIG_DIR / "model" / "net" / "deeplab_small.yaml"


def tiny_run(root: Path, seed: int = 0) -> Path:
    """A run folder as ``uss-train`` writes it (``.hydra/config.yaml`` with the demo's small
    net, ``checkpoints/last.ckpt``) with random weights and BatchNorm statistics; returns the
    checkpoint."""
    torch.manual_seed(seed)
    net = instantiate(OmegaConf.load(NET_YAML))
    assert isinstance(net, DeepLabV2)
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
    (root / ".hydra").mkdir(parents=True)
    (root / "checkpoints").mkdir()
    config = {"run_name": "tiny", "model": {"net": yaml.safe_load(NET_YAML.read_text())}}
    (root / ".hydra" / "config.yaml").write_text(yaml.safe_dump(config))
    ckpt = root / "checkpoints" / "last.ckpt"
    state = {f"segmenter.{k}": v for k, v in net.eval().state_dict().items()}
    torch.save(
        {"state_dict": state, "hyper_parameters": {"class_names": list(CLASS_NAMES)},
         "iteration": 3},
        ckpt,
    )  # fmt: skip
    return ckpt


def colour_model(path: Path, bias: float = 128.0) -> Path:
    """An ONNX segmenter of the project's contract whose label is the argmax of
    ``(bias, R, G, B)`` per pixel (:func:`shared_helpers.colour_labels`)."""
    metadata = SegmenterMetadata(
        class_names=CLASS_NAMES,
        dynamic_classes=("person",),
        mean=(0.485, 0.456, 0.406),
        std=(0.229, 0.224, 0.225),
        head="main",
        experiment="colour",
        checkpoint_sha256="0" * 64,
        version="0.1.0",
    )
    return shared_helpers.colour_model(path, metadata.to_props(), bias=bias)

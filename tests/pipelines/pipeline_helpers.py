"""Helpers of the pipeline tests: composing the real training config, data-path overrides, a
tiny ``uss-train`` run folder and a tiny ONNX segmenter with known output."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnx
import torch
import yaml
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict
from onnx import TensorProto, helper

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.onnx_contract import SegmenterMetadata
from uss_slam.models import DeepLabV2

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
NET_YAML = CONFIG_DIR / "model" / "net" / "deeplab_small.yaml"


def data_overrides(data: dict[str, Path]) -> list[str]:
    """``uss-train`` overrides pointing at the synthetic data of the ``uda_data`` fixture."""
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
    ``(bias, R, G, B)`` per pixel (:func:`colour_labels`)."""
    nodes = [
        helper.make_node("Cast", ["image"], ["x"], to=TensorProto.FLOAT),
        helper.make_node("Transpose", ["x"], ["nchw"], perm=[0, 3, 1, 2]),
        helper.make_node("Conv", ["nchw", "w", "b"], ["logits"]),
        helper.make_node("ArgMax", ["logits"], ["idx"], axis=1, keepdims=0),
        helper.make_node("Cast", ["idx"], ["labels"], to=TensorProto.UINT8),
    ]
    weight = np.zeros((4, 3, 1, 1), np.float32)
    weight[1, 0] = weight[2, 1] = weight[3, 2] = 1.0
    graph = helper.make_graph(
        nodes,
        "colour",
        [helper.make_tensor_value_info("image", TensorProto.UINT8, ["N", "H", "W", 3])],
        [
            helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["N", 4, "H", "W"]),
            helper.make_tensor_value_info("labels", TensorProto.UINT8, ["N", "H", "W"]),
        ],
        initializer=[
            helper.make_tensor("w", TensorProto.FLOAT, weight.shape, weight.ravel()),
            helper.make_tensor("b", TensorProto.FLOAT, [4], [bias, 0.0, 0.0, 0.0]),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 9
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
    helper.set_model_props(model, metadata.to_props())
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def colour_labels(rgb: np.ndarray, bias: float = 128.0) -> np.ndarray:
    """What :func:`colour_model` predicts for ``rgb`` (first maximum wins, as ArgMax)."""
    logits = np.concatenate([np.full(rgb.shape[:2] + (1,), bias), rgb.astype(np.float64)], axis=2)
    return np.argmax(logits, axis=2).astype(np.uint8)

"""PSPNet: pyramid pooling (adaptive pooling as matrix products), two heads at output stride 8,
frozen BN, parameter groups, checkpoints and weights, and the ONNX contract at any input size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch
import torch.nn.functional as F
from hydra.utils import instantiate
from omegaconf import OmegaConf
from shared_helpers import fake_run, segmenter_metadata
from torch import nn

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.onnx_contract import SegmenterMetadata
from uss_slam.export import (
    export_checkpoint,
    export_segmenter,
    load_checkpoint,
    verification_images,
)
from uss_slam.models import PSPNet, SegmenterOutput, load_segmenter_weights
from uss_slam.models.checkpoint import read_checkpoint
from uss_slam.models.pspnet import PyramidPooling, adaptive_avg_pool

torch.set_num_threads(1)

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs" / "model" / "net"


def _small(seed: int = 0, **kwargs: object) -> PSPNet:
    """``pspnet_small`` as configured, with non-trivial BatchNorm statistics."""
    torch.manual_seed(seed)
    cfg = OmegaConf.load(CONFIG_DIR / "pspnet_small.yaml")
    net = instantiate(cfg, **kwargs)
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
    return net


@pytest.mark.parametrize("size", [(13, 17), (6, 7), (2, 3), (1, 1), (41, 29), (12, 12)])
@pytest.mark.parametrize("bins", [1, 2, 3, 6])
def test_adaptive_avg_pool_is_torchs(size: tuple[int, int], bins: int) -> None:
    x = torch.randn(2, 5, *size)
    torch.testing.assert_close(adaptive_avg_pool(x, bins), F.adaptive_avg_pool2d(x, bins))


def test_pyramid_pooling_levels() -> None:
    torch.manual_seed(0)
    ppm = PyramidPooling(16, bins=(1, 2, 3, 6)).eval()
    x = torch.randn(1, 16, 9, 11)
    out = ppm(x)
    assert out.shape == (1, 32, 9, 11) and ppm.out_channels == 32
    assert torch.equal(out[:, :16], x)  # the input itself, then one level of 4 channels per bin
    # The 1x1 level is one value per channel, constant over the map.
    level1 = out[:, 16:20]
    torch.testing.assert_close(level1, level1[:, :, :1, :1].expand_as(level1))
    with pytest.raises(UssSlamError, match="bins must be integers >= 1"):
        PyramidPooling(16, bins=(1, 0))


@pytest.mark.parametrize("size", [(64, 64), (65, 97), (33, 47)])
def test_two_heads_at_one_eighth(size: tuple[int, int]) -> None:
    net = _small()
    expected = tuple((s + 7) // 8 for s in size)
    with torch.no_grad():
        for mode in (True, False):
            net.train(mode)
            out = net(torch.randn(2, 3, *size))
            assert isinstance(out, SegmenterOutput)
            assert out.aux.shape == out.main.shape == (2, 4, *expected)


def test_resnet101_widths_follow_the_paper() -> None:
    net = PSPNet(4, "resnet101")
    assert [s[0].out_channels for s in net.main.ppm.stages] == [512] * 4
    assert net.main.ppm.bins == (1, 2, 3, 6)
    assert net.main.bottleneck[0].in_channels == 4096
    assert net.main.bottleneck[0].out_channels == 512
    assert net.aux.ppm is None and net.aux.bottleneck[0].in_channels == 1024
    assert net.aux.bottleneck[0].out_channels == 256
    assert net.main.classifier.out_channels == net.aux.classifier.out_channels == 4
    assert net.main.dropout.p == 0.1
    # Dilated backbone as DeepLab-v2's: layer4 keeps stride 1, dilation 4.
    assert net.backbone.layer4[0].conv2.dilation == (4, 4)


def test_frozen_batchnorm_covers_the_heads() -> None:
    net = PSPNet(4, "resnet_small", freeze_bn=True).train()
    bns = [m for m in net.modules() if isinstance(m, nn.BatchNorm2d)]
    assert any(m in bns for m in net.main.modules()) and all(not m.training for m in bns)
    assert all(not p.requires_grad for m in bns for p in m.parameters())
    assert all(m.training for m in net.modules() if isinstance(m, nn.Dropout2d))
    trained = PSPNet(4, "resnet_small", freeze_bn=False).train()
    assert all(m.training for m in trained.modules() if isinstance(m, nn.BatchNorm2d))


def test_param_groups_list_every_trainable_parameter_once() -> None:
    net = _small()
    groups = net.param_groups(0.01, head_lr_mult=10.0)
    assert [g["name"] for g in groups] == ["backbone", "heads"]
    assert [g["lr"] for g in groups] == [0.01, 0.1]
    listed = [id(p) for g in groups for p in g["params"]]
    assert len(listed) == len(set(listed))
    assert set(listed) == {id(p) for p in net.parameters() if p.requires_grad}
    heads = {id(p) for p in groups[1]["params"]}
    assert {id(p) for p in net.main.ppm.parameters()} <= heads  # pyramid pooling: head rate


def test_bad_dropout_is_one_line() -> None:
    with pytest.raises(UssSlamError, match=r"model.net.dropout must be a number in \[0, 1\)"):
        PSPNet(4, "resnet_small", dropout=1.5)


def _metadata() -> SegmenterMetadata:
    return segmenter_metadata(CLASS_NAMES, experiment="pspnet")


def _eager(net: nn.Module, images: np.ndarray) -> np.ndarray:
    x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    with torch.no_grad():
        out = net((x - mean) / std).main
        return F.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=True).numpy()


def test_export_follows_the_onnx_contract_at_odd_sizes(tmp_path: Path) -> None:
    net = _small(seed=1).eval()
    result = export_segmenter(
        net, tmp_path / "psp.onnx", _metadata(), trace_size=(65, 81), verify_size=(49, 57)
    )
    assert result.verify["ok"] and result.verify["checker"] == "ok"
    session = ort.InferenceSession(str(result.path), providers=["CPUExecutionProvider"])
    # Sizes whose feature maps (ceil(H/8)) are not multiples of the bins, one below 6.
    for shape, seed in (((1, 37, 53), 1), ((2, 33, 47), 2), ((1, 41, 17), 3)):
        images = verification_images(shape[1:], batch=shape[0], seed=seed)
        logits, labels = session.run(["logits", "labels"], {"image": images})
        assert logits.shape == (shape[0], 4, *shape[1:]) and labels.shape == shape
        assert np.abs(logits - _eager(net, images)).max() <= 1e-4


def test_checkpoint_export_and_weights(tmp_path: Path) -> None:
    net = _small(seed=2).eval()
    ckpt = fake_run(
        tmp_path / "run", net, "psp", net_yaml=CONFIG_DIR / "pspnet_small.yaml", iteration=3
    )
    assert read_checkpoint(ckpt).num_classes == 4
    loaded = load_checkpoint(ckpt)
    assert isinstance(loaded.segmenter, PSPNet) and not loaded.segmenter.training
    for key, value in loaded.segmenter.state_dict().items():
        assert torch.equal(value, net.state_dict()[key]), key
    result = export_checkpoint(ckpt, tmp_path / "out" / "psp.onnx", verify_size=(49, 57))
    images = verification_images((45, 61), batch=1, seed=8)
    logits, _ = ort.InferenceSession(str(result.path)).run(None, {"image": images})
    assert np.abs(logits - _eager(net, images)).max() <= 1e-4

    # model.net.weights_path: the same architecture loads whole; 21 classes load the backbone.
    fresh = PSPNet(4, "resnet_small", freeze_bn=False)
    report = load_segmenter_weights(fresh, ckpt)
    assert report.heads_loaded and report.file_format == "checkpoint"
    voc = PSPNet(21, "resnet_small", freeze_bn=False)
    torch.save(voc.state_dict(), tmp_path / "voc.pt")
    report = load_segmenter_weights(fresh, tmp_path / "voc.pt")
    assert not report.heads_loaded and "file heads have 21 classes, the model has 4" in report.note

"""Loading segmenter weights from local files (never downloads)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
import torchvision
from torch import nn

from uss_slam.core.errors import DataFormatError
from uss_slam.models import DeepLabV2, load_segmenter_weights

torch.set_num_threads(1)


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor], prefix: str) -> bool:
    keys = [k for k in a if k.startswith(prefix)]
    return bool(keys) and all(torch.equal(a[k], b[k]) for k in keys)


def test_other_class_count_keeps_backbone_and_reinitialises_heads(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    torch.manual_seed(1)
    voc = DeepLabV2(num_classes=21, backbone="resnet_small")
    path = tmp_path / "voc21.pt"
    torch.save(voc.state_dict(), path)
    torch.manual_seed(2)
    model = DeepLabV2(num_classes=4, backbone="resnet_small")
    heads_before = {k: v.clone() for k, v in model.state_dict().items()}
    with caplog.at_level(logging.WARNING):
        report = load_segmenter_weights(model, path)
    assert _same(model.state_dict(), voc.state_dict(), "backbone.")
    assert _same(model.state_dict(), heads_before, "aux.")
    assert _same(model.state_dict(), heads_before, "main.")
    assert not report.heads_loaded and report.file_format == "segmenter"
    assert "21 classes" in report.note and "re-initialised" in report.note
    assert "21 classes" in caplog.text


def test_same_class_count_loads_everything_from_a_training_checkpoint(tmp_path: Path) -> None:
    torch.manual_seed(1)
    trained = DeepLabV2(backbone="resnet_small")
    state = {f"segmenter.{k}": v for k, v in trained.state_dict().items()}
    state["d_aux.layers.0.weight"] = torch.zeros(1)  # other module's entries are ignored
    path = tmp_path / "last.ckpt"
    torch.save({"state_dict": state, "iteration": 7}, path)
    torch.manual_seed(2)
    model = DeepLabV2(backbone="resnet_small", weights_path=path)
    assert _same(model.state_dict(), trained.state_dict(), "")
    report = load_segmenter_weights(DeepLabV2(backbone="resnet_small"), path)
    assert report.heads_loaded and report.file_format == "checkpoint" and report.note == ""


def test_torchvision_resnet_state_dict_loads_the_backbone(tmp_path: Path) -> None:
    torch.manual_seed(1)
    source = DeepLabV2(backbone="resnet_small")
    state = {k.removeprefix("backbone."): v for k, v in source.state_dict().items()}
    state = {k: v for k, v in state.items() if not k.startswith(("aux.", "main."))}
    state["fc.weight"] = torch.zeros(1000, 512)
    path = tmp_path / "resnet.pth"
    torch.save(state, path)
    model = DeepLabV2(backbone="resnet_small")
    report = load_segmenter_weights(model, path)
    assert _same(model.state_dict(), source.state_dict(), "backbone.")
    assert report.file_format == "torchvision" and not report.heads_loaded
    assert report.backbone_tensors == sum(1 for k in state if not k.startswith("fc."))


def test_bad_files_name_the_file(tmp_path: Path) -> None:
    model = DeepLabV2(backbone="resnet_small")
    with pytest.raises(DataFormatError, match="weights file not found"):
        load_segmenter_weights(model, tmp_path / "missing.pt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_text("not a checkpoint")
    with pytest.raises(DataFormatError, match=r"garbage\.pt: not a readable torch weights file"):
        load_segmenter_weights(model, garbage)
    unknown = tmp_path / "unknown.pt"
    torch.save({"aux.branches.0.weight": torch.zeros(4, 256, 3, 3)}, unknown)
    with pytest.raises(DataFormatError, match=r"unknown\.pt: unknown weights layout .* Scale"):
        load_segmenter_weights(model, unknown)
    with pytest.raises(DataFormatError, match=r"unknown\.pt: unknown weights layout"):
        DeepLabV2(backbone="resnet_small", weights_path=unknown)  # before building anything
    partial = tmp_path / "partial.pt"
    torch.save({"backbone.conv1.weight": torch.zeros(16, 3, 7, 7)}, partial)
    with pytest.raises(DataFormatError, match=r"partial\.pt: .* backbone tensors missing"):
        load_segmenter_weights(model, partial)
    other = tmp_path / "resnet50.pt"
    torch.save(DeepLabV2(backbone="resnet_small", num_classes=2).state_dict(), other)
    wide = DeepLabV2(backbone="resnet_small")
    wide_state = {k: v for k, v in torch.load(other).items()}
    wide_state["backbone.conv1.weight"] = torch.zeros(64, 3, 7, 7)
    torch.save(wide_state, other)
    with pytest.raises(DataFormatError, match="has shape"):
        load_segmenter_weights(wide, other)


# ---------------------------------------------------------------- files in the real layouts


def _caffe_file(backbone: nn.Module, classes: int, path: Path) -> dict[str, torch.Tensor]:
    """DeepLab-v2's Caffe init (AdaptSegNet's ``DeepLab_resnet_pretrained_init-f81d91e8.pth``,
    ADVENT's ``DeepLab_resnet_pretrained_imagenet.pth``) in its exact key layout: ``Scale.`` +
    the ResNet names (no ``num_batches_tracked``: written by PyTorch 0.3), and the single-level
    ASPP classifier ``Scale.layer5.conv2d_list.{0..3}`` on layer4's 2048 channels."""
    torch.manual_seed(3)
    state = {
        f"Scale.{k}": v.clone()
        for k, v in backbone.state_dict().items()
        if not k.endswith("num_batches_tracked") and not k.startswith("fc.")
    }
    for key, value in state.items():  # loaded statistics that are not the initial ones
        if key.endswith("running_mean"):
            value.normal_()
        elif key.endswith("running_var"):
            value.uniform_(0.5, 2.0)
    channels = backbone.layer4[-1].conv3.out_channels
    for i in range(4):
        state[f"Scale.layer5.conv2d_list.{i}.weight"] = torch.randn(classes, channels, 3, 3)
        state[f"Scale.layer5.conv2d_list.{i}.bias"] = torch.randn(classes)
    torch.save(state, path)
    return state


@pytest.fixture(scope="module")
def resnet101_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A torchvision ResNet-101 state dict (``fc.*`` included) and the Caffe init of the same
    network, both at the real shapes, written from a constructed (random) network."""
    folder = tmp_path_factory.mktemp("r101")
    torch.manual_seed(0)
    resnet = torchvision.models.resnet101()
    torch.save(resnet.state_dict(), folder / "resnet101-63fe2227.pth")
    _caffe_file(resnet, 21, folder / "DeepLab_resnet_pretrained_init-f81d91e8.pth")
    return {
        "torchvision": folder / "resnet101-63fe2227.pth",
        "caffe": folder / "DeepLab_resnet_pretrained_init-f81d91e8.pth",
    }


def test_deeplab_caffe_init_builds_the_caffe_layout_resnet101(
    resnet101_files: dict[str, Path], caplog: pytest.LogCaptureFixture
) -> None:
    path = resnet101_files["caffe"]
    file = torch.load(path)
    with caplog.at_level(logging.INFO, logger="uss_slam.models.weights"):
        model = DeepLabV2(4, "resnet101", weights_path=path)
    assert "read as deeplab-caffe weights (caffe backbone layout)" in caplog.text
    assert "21-class classifier does not fit" in caplog.text  # heads stay initialised
    bb = model.backbone
    # AdaptSegNet's Bottleneck: the stride on the first 1x1 conv; max-pool rounding up.
    assert bb.layout == "caffe" and bb.maxpool.ceil_mode
    assert bb.layer2[0].conv1.stride == (2, 2) and bb.layer2[0].conv2.stride == (1, 1)
    assert bb.layer2[0].downsample[0].stride == (2, 2)
    for stage, dilation in ((bb.layer3, 2), (bb.layer4, 4)):
        for block in stage:
            assert block.conv1.stride == block.conv2.stride == (1, 1)
            assert block.conv2.dilation == (dilation, dilation)
    own = model.state_dict()
    converted = {"Scale.conv1.weight", "Scale.bn1.running_mean"}
    for key, value in file.items():
        if key.startswith("Scale.layer5.") or key in converted:
            continue
        assert torch.equal(own["backbone." + key.removeprefix("Scale.")], value), key
    assert model.batchnorm == "frozen"  # auto, weights loaded
    assert own["backbone.caffe_layout"].item() == 1  # travels with checkpoints


def test_caffe_input_convention_is_converted_exactly() -> None:
    """The Caffe net's conv1 + bn1 on BGR 0-255 minus its mean equal the loaded ones on this
    project's RGB ImageNet-normalised input (away from the zero-padded border)."""
    from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
    from uss_slam.models.weights import CAFFE_MEAN_BGR, _caffe_to_segmenter

    torch.manual_seed(0)
    caffe = {
        "Scale.conv1.weight": torch.randn(8, 3, 7, 7, dtype=torch.float64),
        "Scale.bn1.running_mean": torch.randn(8, dtype=torch.float64),
    }
    ours = _caffe_to_segmenter(caffe)
    rgb = torch.rand(1, 3, 24, 24, dtype=torch.float64)  # 0..1
    bgr_caffe = 255 * rgb.flip(1) - torch.tensor(CAFFE_MEAN_BGR, dtype=torch.float64).view(3, 1, 1)
    mean = torch.tensor(IMAGENET_MEAN, dtype=torch.float64).view(3, 1, 1)
    std = torch.tensor(IMAGENET_STD, dtype=torch.float64).view(3, 1, 1)
    normalised = (rgb - mean) / std
    ref = F.conv2d(bgr_caffe, caffe["Scale.conv1.weight"], padding=3, stride=2)
    ref = ref - caffe["Scale.bn1.running_mean"].view(1, -1, 1, 1)
    got = F.conv2d(normalised, ours["backbone.conv1.weight"], padding=3, stride=2)
    got = got - ours["backbone.bn1.running_mean"].view(1, -1, 1, 1)
    inner = (slice(None), slice(None), slice(2, -2), slice(2, -2))
    torch.testing.assert_close(got[inner], ref[inner], rtol=1e-9, atol=1e-8)


def test_caffe_layout_is_another_function_and_its_classifier_loads_as_main(
    tmp_path: Path,
) -> None:
    """Small network: a Caffe file with the model's class count loads the main head from
    ``Scale.layer5``; the same weights in the torchvision layout compute something else."""
    torch.manual_seed(1)
    source = DeepLabV2(4, "resnet_small", batchnorm="frozen")
    path = tmp_path / "caffe_small.pth"
    file = _caffe_file(source.backbone, 4, path)
    model = DeepLabV2(4, "resnet_small", weights_path=path)
    for i in range(4):
        assert torch.equal(
            model.main.branches[i].weight, file[f"Scale.layer5.conv2d_list.{i}.weight"]
        )
    same_weights = DeepLabV2(4, "resnet_small", batchnorm="frozen")
    state = {k: v for k, v in model.state_dict().items() if k != "backbone.caffe_layout"}
    same_weights.load_state_dict(state)
    x = torch.randn(1, 3, 33, 33)
    assert not torch.allclose(model.eval()(x).main, same_weights.eval()(x).main)
    # An even size: the caffe max-pool rounds up.
    assert model(torch.randn(1, 3, 32, 32)).main.shape[-2:] == (5, 5)
    assert same_weights(torch.randn(1, 3, 32, 32)).main.shape[-2:] == (4, 4)
    # Its state dict loads strictly into a model built without the file (export rebuilds the
    # net from its config) and switches that model to the caffe layout.
    rebuilt = DeepLabV2(4, "resnet_small", batchnorm="frozen")
    rebuilt.load_state_dict(model.state_dict())
    assert rebuilt.backbone.layout == "caffe" and rebuilt.backbone.layer2[0].conv1.stride == (2, 2)
    x = torch.randn(1, 3, 33, 33)
    torch.testing.assert_close(rebuilt.eval()(x).main, model.eval()(x).main, rtol=0, atol=0)
    # Its checkpoint is read back in the caffe layout (the marker buffer).
    saved = tmp_path / "segmenter.pt"
    torch.save(model.state_dict(), saved)
    assert DeepLabV2(4, "resnet_small", weights_path=saved).backbone.layout == "caffe"
    with pytest.raises(DataFormatError, match="caffe backbone layout, the model is built in"):
        load_segmenter_weights(DeepLabV2(4, "resnet_small"), saved)


@pytest.mark.parametrize("depth", ["resnet50", "resnet101"])
def test_torchvision_resnet_files_load_into_their_backbone(
    depth: str, resnet101_files: dict[str, Path], tmp_path: Path
) -> None:
    if depth == "resnet101":
        path = resnet101_files["torchvision"]
    else:
        torch.manual_seed(0)
        path = tmp_path / "resnet50-0676ba61.pth"
        torch.save(torchvision.models.resnet50().state_dict(), path)
    file = torch.load(path)
    model = DeepLabV2(4, depth, weights_path=path)
    own = model.state_dict()
    assert model.backbone.layout == "torchvision" and not model.backbone.maxpool.ceil_mode
    assert model.backbone.layer2[0].conv2.stride == (2, 2)
    for key, value in file.items():
        if not key.startswith("fc."):
            assert torch.equal(own["backbone." + key], value), key


def test_files_that_do_not_fit_the_network_name_file_and_network(
    resnet101_files: dict[str, Path],
) -> None:
    path = resnet101_files["torchvision"]
    with pytest.raises(
        DataFormatError,
        match=r"resnet101-63fe2227\.pth: .* model lacks .*"
        r"does not fit model.net.backbone=resnet50",
    ):
        DeepLabV2(4, "resnet50", weights_path=path)
    with pytest.raises(DataFormatError, match=r"does not fit model.net.backbone=resnet_small"):
        DeepLabV2(4, "resnet_small", weights_path=path)  # small network: other names

"""DeepLabV2: ASPP sums all four rates, output stride 8, BatchNorm modes, parameter groups."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch
from torch import nn

from uss_slam.core.errors import UssSlamError
from uss_slam.models import ASPPClassifier, DeepLabV2, PSPNet, SegmenterOutput, output_size

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def small() -> DeepLabV2:
    torch.manual_seed(0)
    return DeepLabV2(num_classes=4, backbone="resnet_small", batchnorm="frozen")


@pytest.fixture(scope="module")
def resnet101() -> DeepLabV2:
    torch.manual_seed(0)
    return DeepLabV2(num_classes=4, backbone="resnet101", batchnorm="frozen")


def test_aspp_output_is_the_sum_of_all_four_branches() -> None:
    torch.manual_seed(0)
    aspp = ASPPClassifier(8, 4, rates=(6, 12, 18, 24))
    x = torch.randn(1, 8, 30, 30)
    with torch.no_grad():
        expected = sum(branch(x) for branch in aspp.branches)
        assert [b.dilation for b in aspp.branches] == [(6, 6), (12, 12), (18, 18), (24, 24)]
        torch.testing.assert_close(aspp(x), expected)


@pytest.mark.parametrize("branch", [0, 1, 2, 3])
def test_every_aspp_branch_changes_the_output(branch: int) -> None:
    torch.manual_seed(0)
    aspp = ASPPClassifier(8, 4)
    x = torch.randn(1, 8, 30, 30)
    with torch.no_grad():
        before = aspp(x)
        aspp.branches[branch].weight.zero_()
        aspp.branches[branch].bias.zero_()
        after = aspp(x)
    assert (before - after).abs().max() > 1e-3


@pytest.mark.parametrize("size", [(64, 64), (65, 97), (33, 47), (321, 321)])
def test_heads_are_at_one_eighth_for_even_and_odd_sizes(
    small: DeepLabV2, size: tuple[int, int]
) -> None:
    expected = tuple((s + 7) // 8 for s in size)
    assert output_size(*size) == expected
    with torch.no_grad():
        for mode in (True, False):
            small.train(mode)
            out = small(torch.randn(2, 3, *size))
            assert isinstance(out, SegmenterOutput)
            assert out.aux.shape == out.main.shape == (2, 4, *expected)


def test_resnet101_layout_follows_deeplab_v2(resnet101: DeepLabV2) -> None:
    backbone = resnet101.backbone
    assert len(backbone.layer3) == 23 and len(backbone.layer4) == 3
    assert backbone.out_channels == (1024, 2048)
    for stage, dilation in ((backbone.layer3, 2), (backbone.layer4, 4)):
        for block in stage:  # every block, the first included
            assert block.conv2.dilation == (dilation, dilation)
            assert block.conv2.padding == (dilation, dilation)
            assert block.conv2.stride == (1, 1)
    assert backbone.layer2[0].conv2.stride == (2, 2)
    with torch.no_grad():
        out = resnet101(torch.randn(1, 3, 65, 49))
    assert out.main.shape == out.aux.shape == (1, 4, 9, 7)


@pytest.mark.parametrize("fixture", ["small", "resnet101"])
def test_param_groups_cover_every_trainable_parameter_once(
    fixture: str, request: pytest.FixtureRequest
) -> None:
    model: DeepLabV2 = request.getfixturevalue(fixture)
    groups = model.param_groups(2.5e-4)
    ids = [id(p) for g in groups for p in g["params"]]
    assert len(ids) == len(set(ids))
    trainable = {id(p) for p in model.parameters() if p.requires_grad}
    assert set(ids) == trainable
    head_ids = {id(p) for p in model.aux.parameters()} | {id(p) for p in model.main.parameters()}
    by_name = {g["name"]: g for g in groups}
    assert by_name["heads"]["lr"] == pytest.approx(2.5e-3)
    assert by_name["backbone"]["lr"] == pytest.approx(2.5e-4)
    assert {id(p) for p in by_name["heads"]["params"]} == head_ids
    # Frozen BN: the only parameters left out are BatchNorm affine terms.
    frozen = [p for p in model.parameters() if not p.requires_grad]
    bn_params = [
        p for m in model.modules() if isinstance(m, nn.BatchNorm2d) for p in m.parameters()
    ]
    assert {id(p) for p in frozen} == {id(p) for p in bn_params}


def test_unfrozen_bn_params_join_the_backbone_group() -> None:
    model = DeepLabV2(backbone="resnet_small", batchnorm="trained")
    ids = [id(p) for g in model.param_groups(1.0) for p in g["params"]]
    assert sorted(ids) == sorted(id(p) for p in model.parameters())


@pytest.mark.parametrize("mode", ["trained", "frozen", "reference"])
def test_batchnorm_modes(mode: str) -> None:
    """trained: batch statistics, running ones move, affine learnt; frozen: loaded statistics,
    nothing moves; reference: batch statistics, running ones move, affine frozen."""
    torch.manual_seed(0)
    model = DeepLabV2(backbone="resnet_small", batchnorm=mode).train()
    assert model.batchnorm == mode
    before = model.backbone.bn1.running_mean.clone()
    model(torch.randn(2, 3, 40, 40) * 3 + 1)
    moved = not torch.equal(before, model.backbone.bn1.running_mean)
    bns = [m for m in model.backbone.modules() if isinstance(m, nn.BatchNorm2d)]
    assert moved is (mode != "frozen")
    assert all(m.training is (mode != "frozen") for m in bns)
    assert all(p.requires_grad is (mode == "trained") for m in bns for p in m.parameters())
    trainable = {id(p) for g in model.param_groups(1.0) for p in g["params"]}
    assert any(id(m.weight) in trainable for m in bns) is (mode == "trained")
    model.eval()  # evaluation and export: running statistics in every mode
    assert not any(m.training for m in bns)


def test_unknown_backbone_and_weights_are_clear_errors() -> None:
    with pytest.raises(UssSlamError, match="unknown backbone 'resnet18'"):
        DeepLabV2(backbone="resnet18")
    with pytest.raises(UssSlamError, match="ResNet50_Weights.NOPE"):
        DeepLabV2(backbone="resnet50", backbone_weights="NOPE")  # fails before any download
    with pytest.raises(UssSlamError, match="no ImageNet weights"):
        DeepLabV2(backbone="resnet_small", backbone_weights="IMAGENET1K_V1")


@pytest.mark.parametrize("segmenter", [DeepLabV2, PSPNet])
def test_batchnorm_is_frozen_by_default_only_with_loaded_weights(
    segmenter: type, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A randomly initialised frozen BatchNorm is the identity for the whole run: by default
    (``batchnorm="auto"``) it trains without weights and is frozen with them."""
    torch.manual_seed(0)
    scratch = segmenter(backbone="resnet_small").train()
    assert scratch.batchnorm == "trained" and scratch.freeze_bn is False
    assert scratch.backbone.bn1.training and scratch.backbone.bn1.weight.requires_grad
    path = tmp_path / "weights.pt"
    torch.save(scratch.state_dict(), path)
    loaded = segmenter(backbone="resnet_small", weights_path=path).train()
    assert loaded.batchnorm == "frozen" and loaded.freeze_bn is True
    assert not loaded.backbone.bn1.training and not loaded.backbone.bn1.weight.requires_grad
    # An explicit choice stays, with a warning where it freezes the identity.
    with caplog.at_level(logging.WARNING, logger="uss_slam.models.backbone"):
        assert segmenter(backbone="resnet_small", batchnorm="frozen").batchnorm == "frozen"
    assert "stays the identity" in caplog.text
    kept = segmenter(backbone="resnet_small", weights_path=path, batchnorm="trained")
    assert kept.batchnorm == "trained"
    # The former switch still reads, for Python callers.
    assert segmenter(backbone="resnet_small", freeze_bn=False).batchnorm == "trained"
    with pytest.raises(UssSlamError, match="^model.net.batchnorm must be one of auto, trained"):
        segmenter(backbone="resnet_small", batchnorm="yes")
    with pytest.raises(UssSlamError, match="freeze_bn must be true, false or auto"):
        segmenter(backbone="resnet_small", freeze_bn="yes")
    with pytest.raises(UssSlamError, match="contradicts model.net.batchnorm=reference"):
        segmenter(backbone="resnet_small", freeze_bn=True, batchnorm="reference")


def test_pspnet_refuses_the_reference_batchnorm_mode_in_one_line() -> None:
    with pytest.raises(UssSlamError, match="^model.net.batchnorm=reference is not supported") as e:
        PSPNet(4, "resnet_small", batchnorm="reference")
    assert "\n" not in str(e.value)


def test_resnet_without_weights_warns_or_is_refused(caplog: pytest.LogCaptureFixture) -> None:
    with pytest.raises(UssSlamError, match="^model.net.weights_path: not set") as e:
        DeepLabV2(backbone="resnet50", allow_random_init=False)
    assert "model.net.allow_random_init=true" in str(e.value) and "\n" not in str(e.value)
    with caplog.at_level(logging.WARNING, logger="uss_slam.models.deeplab"):
        DeepLabV2(backbone="resnet50")
    assert "resnet50 starts from random weights" in caplog.text

"""Loading segmenter weights from local files (never downloads)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch

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
    partial = tmp_path / "partial.pt"
    torch.save({"aux.branches.0.weight": torch.zeros(4, 256, 3, 3)}, partial)
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

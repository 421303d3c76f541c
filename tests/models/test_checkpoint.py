"""read_checkpoint: a uss-train checkpoint's segmenter weights, classes and iteration, and one
clear error naming the file for every kind of bad file."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
import torch

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import DataFormatError
from uss_slam.models import DeepLabV2
from uss_slam.models.checkpoint import read_checkpoint


def _state(num_classes: int = 4) -> dict[str, torch.Tensor]:
    torch.manual_seed(0)
    net = DeepLabV2(num_classes, "resnet_small")
    state = {f"segmenter.{k}": v for k, v in net.state_dict().items()}
    state["d_main.layers.0.weight"] = torch.ones(2, 4, 4, 4)
    return state


def _save(path: Path, blob: object) -> Path:
    torch.save(blob, path)
    return path


def test_reads_a_uss_train_checkpoint(tmp_path: Path) -> None:
    state = _state()
    hparams = {"class_names": list(CLASS_NAMES), "backbone": "resnet_small", "max_iters": 10}
    ckpt = _save(
        tmp_path / "last.ckpt",
        {"state_dict": state, "hyper_parameters": hparams, "iteration": 7, "epoch": 0},
    )
    info = read_checkpoint(ckpt, num_classes=4)
    assert info.path == ckpt and info.iteration == 7
    assert info.class_names == CLASS_NAMES and info.num_classes == 4
    assert info.hyper_parameters == hparams
    assert set(info.state_dict) == set(state)
    assert set(info.segmenter_state) == {k.removeprefix("segmenter.") for k in state} - {
        "d_main.layers.0.weight"
    }
    net = DeepLabV2(4, "resnet_small")
    net.load_state_dict(info.segmenter_state, strict=True)
    assert torch.equal(net.main.branches[0].weight, state["segmenter.main.branches.0.weight"])


def test_class_names_default_and_iteration_optional(tmp_path: Path) -> None:
    ckpt = _save(tmp_path / "a.ckpt", {"state_dict": _state(), "hyper_parameters": {}})
    info = read_checkpoint(ckpt)
    assert info.class_names == CLASS_NAMES and info.iteration is None


def _error(path: Path, **kwargs: object) -> str:
    with pytest.raises(DataFormatError) as info:
        read_checkpoint(path, **kwargs)  # type: ignore[arg-type]
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    return message.removeprefix(f"{path}: ")


def test_missing_empty_and_directory(tmp_path: Path) -> None:
    assert _error(tmp_path / "none.ckpt") == "checkpoint not found"
    (tmp_path / "empty.ckpt").write_bytes(b"")
    assert _error(tmp_path / "empty.ckpt") == "empty file (expected a uss-train .ckpt)"
    assert _error(tmp_path) == "is not a file (expected a uss-train .ckpt)"


def test_truncated_and_random_bytes(tmp_path: Path) -> None:
    good = _save(tmp_path / "good.ckpt", {"state_dict": _state(), "hyper_parameters": {}})
    data = good.read_bytes()
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(data[: len(data) // 2])
    assert _error(truncated).startswith(
        "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt (RuntimeError: "
    )
    noise = tmp_path / "noise.ckpt"
    for seed in range(20):  # random bytes fail in several ways inside torch.load
        noise.write_bytes(np.random.default_rng(seed).bytes(4096))
        assert _error(noise).startswith(
            "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt ("
        )
    assert _error(noise).startswith(
        "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt ("
    )
    pickled = tmp_path / "pickled.ckpt"
    # A Lightning checkpoint whose hyper-parameters are pickled objects, not plain values.
    _save(pickled, {"state_dict": {}, "hyper_parameters": argparse.Namespace(lr=0.1)})
    assert _error(pickled) == (
        "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt "
        "(UnpicklingError: Unsupported global: GLOBAL argparse.Namespace was not an allowed global by default)"
    )


def test_not_a_lightning_checkpoint(tmp_path: Path) -> None:
    state = _state()
    plain = _save(
        tmp_path / "plain.pt", {k.removeprefix("segmenter."): v for k, v in state.items()}
    )
    assert _error(plain) == "not a Lightning checkpoint: no 'state_dict' (a plain state dict?)"
    listed = _save(tmp_path / "list.pt", [1, 2])
    assert _error(listed) == "not a Lightning checkpoint: holds a list, expected a dict"
    no_hparams = _save(tmp_path / "nohp.ckpt", {"state_dict": state})
    assert _error(no_hparams) == (
        "not a uss-train checkpoint: no 'hyper_parameters' (class names, backbone)"
    )
    no_segmenter = _save(
        tmp_path / "noseg.ckpt",
        {"state_dict": {"d_main.layers.0.weight": torch.ones(1)}, "hyper_parameters": {}},
    )
    assert _error(no_segmenter) == "checkpoint state_dict has no 'segmenter.*' entries"
    no_head = {k: v for k, v in state.items() if not k.startswith("segmenter.main.")}
    headless = _save(tmp_path / "headless.ckpt", {"state_dict": no_head, "hyper_parameters": {}})
    assert _error(headless) == (
        "no 4-D 'segmenter.main.branches.0.weight' or 'segmenter.main.classifier.weight' "
        "(not a DeepLab-v2 or PSPNet segmenter?)"
    )


def test_class_count_mismatches(tmp_path: Path) -> None:
    three = _save(
        tmp_path / "three.ckpt",
        {"state_dict": _state(3), "hyper_parameters": {"class_names": ["bg", "person", "chair"]}},
    )
    assert read_checkpoint(three, num_classes=3).num_classes == 3
    assert (
        _error(three, num_classes=4) == "checkpoint has 3 classes (bg, person, chair), expected 4"
    )
    disagree = _save(tmp_path / "dis.ckpt", {"state_dict": _state(3), "hyper_parameters": {}})
    assert _error(disagree) == (
        "hyper_parameters.class_names lists 4 classes, the segmenter's heads output 3"
    )
    bad_names = _save(
        tmp_path / "names.ckpt",
        {"state_dict": _state(), "hyper_parameters": {"class_names": "person"}},
    )
    assert _error(bad_names) == (
        "hyper_parameters.class_names must be a list of names, got 'person'"
    )

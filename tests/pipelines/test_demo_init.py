"""The demo's pretrained init (``pipelines/assets/deeplab_small_init.pt``): it loads into
``deeplab_small`` through ``model.net.weights_path``, its sha256 is the one its README records,
the README says the commands that make it, and the extraction reproduces a checkpoint's
segmenter exactly."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch

from uss_slam.core.errors import DataFormatError
from uss_slam.core.files import file_sha256
from uss_slam.pipelines.assets import demo_init_path, extract_segmenter
from uss_slam.pipelines.runs import compose_config

README = Path(__file__).resolve().parents[2] / "pipelines" / "assets" / "README.md"


def _net(weights: Path | None):
    from hydra.utils import instantiate

    overrides = ["model/net=deeplab_small"]
    if weights is not None:
        overrides.append(f"model.net.weights_path={weights}")
    return instantiate(compose_config("train", overrides).model.net)


def test_init_loads_into_deeplab_small_through_weights_path() -> None:
    path = demo_init_path()
    assert path.is_file(), path
    state = torch.load(path, map_location="cpu", weights_only=True)
    net = _net(path)
    loaded = net.state_dict()
    assert set(state) == set(loaded)
    for key, value in state.items():
        assert value.dtype == (torch.float32 if value.is_floating_point() else value.dtype), key
        assert torch.equal(loaded[key], value), key
    assert not torch.equal(_net(None).state_dict()["main.branches.0.weight"],
                           state["main.branches.0.weight"])  # fmt: skip


def test_readme_records_sha256_and_the_commands() -> None:
    text = README.read_text()
    (sha,) = re.findall(r"sha256: `([0-9a-f]{64})`", text)
    assert file_sha256(demo_init_path()) == sha
    assert (
        "uss-synth voc --images 800 --style mixed --outfits all --near 0.3 --seed 900 --out DIR"
        in text
    )
    assert "uss-train experiment=pretrain data.source.root=DIR/VOCdevkit/VOC2012 seed=0" in text
    assert re.search(r"commit [0-9a-f]{7,40}\b", text)
    assert re.search(r"mIoU 0\.\d{4}", text)


def test_extraction_is_the_checkpoints_segmenter(tmp_path: Path) -> None:
    state = {
        "segmenter.backbone.conv1.weight": torch.randn(4, 3, 3, 3, dtype=torch.float64),
        "segmenter.backbone.bn1.num_batches_tracked": torch.tensor(7),
        "segmenter.main.weight": torch.randn(2, 4),
        "d_main.weight": torch.randn(3),
    }
    ckpt = tmp_path / "run.ckpt"
    torch.save({"state_dict": state, "iteration": 1800, "optimizer_states": [{}]}, ckpt)
    first = extract_segmenter(ckpt, tmp_path / "a.pt")
    second = extract_segmenter(ckpt, tmp_path / "b.pt")
    assert (first.tensors, first.iteration) == (3, 1800)
    assert first.sha256 == second.sha256 == file_sha256(tmp_path / "b.pt")
    out = torch.load(first.path, weights_only=True)
    assert sorted(out) == ["backbone.bn1.num_batches_tracked", "backbone.conv1.weight",
                           "main.weight"]  # fmt: skip
    assert out["backbone.conv1.weight"].dtype == torch.float32
    assert out["backbone.bn1.num_batches_tracked"].dtype == torch.int64
    assert torch.equal(out["main.weight"], state["segmenter.main.weight"])


def test_extraction_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="missing.ckpt.*not found"):
        extract_segmenter(tmp_path / "missing.ckpt", tmp_path / "x.pt")
    bare = tmp_path / "bare.ckpt"
    torch.save({"state_dict": {"d_main.weight": torch.zeros(1)}}, bare)
    with pytest.raises(DataFormatError, match="bare.ckpt.*no 'segmenter"):
        extract_segmenter(bare, tmp_path / "x.pt")
    assert not (tmp_path / "x.pt").exists()

"""``uss-export ensemble=[...]`` (FDA's multi-band ensemble): one graph whose softmax is the mean
of the members' softmax and whose labels are the argmax of that mean, computed here from each
member's own single export; its metadata names every checkpoint; bad ensembles are one line."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch
from shared_helpers import fake_run, tiny_net

from uss_slam.core.errors import DataFormatError
from uss_slam.core.onnx_contract import SegmenterMetadata
from uss_slam.export import SegmenterExport, export_checkpoint, verification_images


def _softmax(logits: np.ndarray) -> np.ndarray:
    shifted = np.exp(logits - logits.max(axis=1, keepdims=True))
    return shifted / shifted.sum(axis=1, keepdims=True)


@pytest.fixture(scope="module")
def three_runs(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("fda_runs")
    return [fake_run(root / f"b{i}", tiny_net(seed=20 + i), run_name=f"fda_b{i}") for i in range(3)]


def test_ensemble_is_the_mean_of_its_members(three_runs: list[Path], tmp_path: Path) -> None:
    images = verification_images((45, 61), batch=2, seed=3)
    probs, singles = [], []
    for i, ckpt in enumerate(three_runs):
        single = export_checkpoint(ckpt, tmp_path / f"single{i}.onnx")
        logits, _ = ort.InferenceSession(str(single.path)).run(None, {"image": images})
        probs.append(_softmax(logits))
        singles.append(single)
    result = export_checkpoint(three_runs[0], tmp_path / "ens.onnx", ensemble=three_runs[1:])
    logits, labels = ort.InferenceSession(str(result.path)).run(None, {"image": images})
    mean = np.mean(probs, axis=0)
    assert np.abs(_softmax(logits) - mean).max() <= 1e-5
    agree = (labels == mean.argmax(axis=1)).mean()
    assert agree >= 0.999  # ties between near-equal classes may fall either way
    assert not all((labels == _softmax(p).argmax(1)).all() for p in probs)  # not one member's
    meta = SegmenterMetadata.from_props(
        ort.InferenceSession(str(result.path)).get_modelmeta().custom_metadata_map
    )
    assert meta.experiment == "fda_b0+fda_b1+fda_b2"
    hashes = [hashlib.sha256(c.read_bytes()).hexdigest() for c in three_runs]
    assert meta.checkpoint_sha256 == ",".join(hashes)
    assert result.verify["ok"] and result.verify["label_agreement"] >= 0.999


def test_one_segmenter_without_members_is_unchanged() -> None:
    net = tiny_net(seed=4)
    images = torch.from_numpy(verification_images((33, 41), batch=1, seed=2))
    with torch.no_grad():
        plain = SegmenterExport(net).eval()(images)
        listed = SegmenterExport(net, members=[]).eval()(images)
    assert torch.equal(plain[0], listed[0]) and torch.equal(plain[1], listed[1])


def test_cli_default_name_and_bad_ensembles(
    three_runs: list[Path], tmp_path: Path, uss_export: Callable[..., tuple[int, str, str]]
) -> None:
    a, b, c = (str(p) for p in three_runs)
    code, out, err = uss_export(f"ckpt_path={a}", f"ensemble=[{b},{c}]", "out_dir=models")
    assert code == 0, err
    assert (tmp_path / "models" / "fda_b0_ensemble3.onnx").is_file()
    assert "fda_b0_ensemble3.onnx" in out
    bad = {
        f"ensemble=[{b},{b}]": "ensemble",
        f"ensemble=[{a}]": "ensemble: ",
        f"ensemble=[{b},{Path(b).parent}/../checkpoints/last.ckpt]": "same file",
        f"ensemble=[{tmp_path / 'missing.ckpt'}]": "ensemble=",
    }
    for override, expected in bad.items():
        code, out, err = uss_export(f"ckpt_path={a}", override, "out_dir=bad")
        lines = err.strip().splitlines()
        assert code == 1 and len(lines) == 1 and expected in lines[0], (override, err)
        assert not (tmp_path / "bad").exists() or not any((tmp_path / "bad").iterdir())


def test_members_with_other_classes_are_refused(three_runs: list[Path], tmp_path: Path) -> None:
    other = fake_run(tmp_path / "other", tiny_net(seed=30), run_name="other")
    state = torch.load(other, weights_only=False)
    state["hyper_parameters"]["class_names"] = list(
        reversed(state["hyper_parameters"]["class_names"])
    )
    torch.save(state, other)
    with pytest.raises(DataFormatError, match="differ from ckpt_path's"):
        export_checkpoint(three_runs[0], tmp_path / "x.onnx", ensemble=[other])
    assert not (tmp_path / "x.onnx").exists()

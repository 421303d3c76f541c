"""studies/retrain_check.py on fake checkpoints and ONNX graphs: equal, renamed and changed
tensors, and a missing file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from onnx import helper, numpy_helper

from uss_slam.testing.scripts import load_script

check = load_script(Path(__file__).resolve().parents[2] / "studies" / "retrain_check.py")


def _model(folder: Path, onnx_path: Path, state: dict, weight: np.ndarray) -> None:
    (folder / "checkpoints").mkdir(parents=True)
    torch.save({"state_dict": state}, folder / "checkpoints" / "last.ckpt")
    init = numpy_helper.from_array(weight, "w")
    node = helper.make_node("Add", ["x", "w"], ["y"])
    io = [helper.make_tensor_value_info(n, onnx.TensorProto.FLOAT, [2]) for n in ("x", "y")]
    graph = helper.make_graph([node], "g", [io[0]], [io[1]], [init])
    onnx_path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(helper.make_model(graph), str(onnx_path))


def test_renamed_discriminators_are_the_same_tensors_and_a_change_is_seen(tmp_path: Path) -> None:
    w = np.array([1.0, 2.0], np.float32)
    old = {"net.a": torch.ones(3), "d_aux.l.weight": torch.zeros(2)}
    new = {"net.a": torch.ones(3), "method.d_aux.l.weight": torch.zeros(2)}
    _model(tmp_path / "s/train/m_s0", tmp_path / "s/exports/m_s0/m_s0.onnx", old, w)
    _model(tmp_path / "r/m_s0", tmp_path / "r/m_s0/retrain.onnx", new, w)
    r = check.compare(tmp_path / "s", tmp_path / "r", "m_s0")
    assert r["tensors_equal"] == r["tensors"] == 2 and r["keys_equal"] and r["onnx_equal"]
    changed = {"net.a": torch.ones(3) * (1 + 1e-7), "method.d_aux.l.weight": torch.zeros(2)}
    _model(tmp_path / "r2/m_s0", tmp_path / "r2/m_s0/retrain.onnx", changed, w + 1e-6)
    r = check.compare(tmp_path / "s", tmp_path / "r2", "m_s0")
    assert r["tensors_equal"] == 1 and not r["onnx_equal"]
    with pytest.raises(SystemExit, match="no such checkpoint"):
        check.compare(tmp_path / "s", tmp_path / "missing", "m_s0")

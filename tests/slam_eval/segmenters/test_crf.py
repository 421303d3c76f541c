"""Dense-CRF refinement (``segmenter.crf=true``): a blurry mask snaps to a colour edge; the ONNX
segmenter with and without it; the ``segmentation.crf`` row of the run's timing table."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from shared_helpers import slam_run_config
from test_onnx_segmenter import _metadata, tiny_model

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.segmenters.crf import DenseCrf, softmax
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

PERSON = 1


def _edge_scene(flat: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A 64x48 image, dark left of column 32 and bright from it on (or flat grey), and
    probabilities of a blurry person mask whose 0.5 crossing lies 8 px right of the edge."""
    h, w = 48, 64
    rgb = np.full((h, w, 3), 120, np.uint8)
    if not flat:
        rgb[:, :32] = (40, 40, 40)
        rgb[:, 32:] = (200, 180, 160)
    logits = np.full((4, h, w), -5.0, np.float32)
    logits[0] = 0.0
    logits[PERSON] = ((np.arange(w) - 40) / 6.0)[None, :]
    return rgb, softmax(logits)


def _first_person_column(labels: np.ndarray) -> list[int]:
    return [int(np.argmax(row == PERSON)) for row in labels]


def test_crf_snaps_a_blurry_mask_to_the_colour_edge() -> None:
    rgb, prob = _edge_scene()
    before = prob.argmax(axis=0)
    assert set(_first_person_column(before)) == {41}  # the network's blurry boundary
    refined = DenseCrf().refine(rgb, prob)
    assert refined.shape == prob.shape and refined.dtype == np.float32
    np.testing.assert_allclose(refined.sum(axis=0), 1.0, atol=1e-5)
    after = refined.argmax(axis=0)
    # Every row: person exactly on the bright side of the edge, nowhere on the dark side.
    assert set(_first_person_column(after)) == {32}
    assert (after[:, 32:] == PERSON).all() and not (after[:, :32] == PERSON).any()
    # The edge placed it: on a flat image the same probabilities give no boundary at column 32
    # (the kernels only smooth; here the larger background area wins everywhere).
    flat_rgb, flat_prob = _edge_scene(flat=True)
    flat = DenseCrf().refine(flat_rgb, flat_prob).argmax(axis=0)
    assert not (flat[:, 32:] == PERSON).all()


def test_crf_parameters_from_the_config() -> None:
    assert DenseCrf.from_config(None, "segmenter.crf_params") == DenseCrf()
    crf = DenseCrf.from_config({"iterations": 10, "bilateral_sxy": 67}, "segmenter.crf_params")
    assert (crf.iterations, crf.bilateral_sxy, crf.gaussian_sxy) == (10, 67, 3.0)
    with pytest.raises(UssSlamError, match=r"segmenter.crf_params: unknown key 'sxy'; known: "):
        DenseCrf.from_config({"sxy": 3}, "segmenter.crf_params")
    with pytest.raises(UssSlamError, match=r"crf_params.iterations must be a whole number >= 1"):
        DenseCrf.from_config({"iterations": 0}, "segmenter.crf_params")
    with pytest.raises(UssSlamError, match=r"crf_params.bilateral_srgb must be a number > 0"):
        DenseCrf.from_config({"bilateral_srgb": -1}, "segmenter.crf_params")
    rgb, prob = _edge_scene()
    with pytest.raises(UssSlamError, match=r"expected an \(48, 64, 3\) uint8 image"):
        DenseCrf().refine(rgb[:10], prob)


def _scene_image() -> np.ndarray:
    """An RGB image for the tiny model (logits 128, R, G, B): a red block on grey with noise."""
    rng = np.random.default_rng(0)
    rgb = np.full((40, 56, 3), 100, np.uint8)
    rgb[10:30, 20:44] = (180, 60, 60)
    return np.clip(rgb + rng.integers(-40, 40, rgb.shape), 0, 255).astype(np.uint8)


def test_onnx_segmenter_with_and_without_crf(tmp_path: Path) -> None:
    path = tiny_model(tmp_path / "m.onnx", _metadata(), bias=150.0)
    rgb = _scene_image()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    logits, labels = session.run(["logits", "labels"], {"image": rgb[None]})

    plain = OnnxSegmenter(path)
    np.testing.assert_array_equal(plain.infer(rgb), labels[0])  # crf=false: the model's labels
    assert plain.crf is None and plain.stage_times() == {}

    crf = OnnxSegmenter(path, crf=True, crf_params={"iterations": 3})
    expected = DenseCrf(iterations=3).refine(rgb, softmax(logits[0])).argmax(axis=0)
    refined = crf.infer(rgb)
    np.testing.assert_array_equal(refined, expected.astype(np.uint8))
    assert (refined != labels[0]).any()  # the noisy pixels changed
    times = crf.stage_times()
    assert set(times) == {"crf"} and times["crf"][0] > 0 and times["crf"][1] >= 0
    assert crf.stage_times() == {}  # read once
    # With a threshold the refined probabilities are thresholded.
    both = OnnxSegmenter(path, crf=True, threshold=0.9)
    assert both.infer(rgb).shape == rgb.shape[:2] and set(both.stage_times()) == {"crf"}


def test_crf_refusals(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tiny_model(tmp_path / "m.onnx", _metadata())
    with pytest.raises(UssSlamError, match="segmenter.crf must be true or false, got 'yes'"):
        OnnxSegmenter(path, crf="yes")  # type: ignore[arg-type]
    with pytest.raises(UssSlamError, match="segmenter.crf_params: unknown key"):
        OnnxSegmenter(path, crf=True, crf_params={"iters": 5})
    labels_only = tmp_path / "labels.onnx"
    model = onnx.load(str(path))
    del model.graph.output[0]
    onnx.save(model, str(labels_only))
    with pytest.raises(DataFormatError, match=r"segmenter.crf needs the model's 'logits'"):
        OnnxSegmenter(labels_only, crf=True)
    monkeypatch.setitem(sys.modules, "pydensecrf.densecrf", None)  # not installed
    with pytest.raises(UssSlamError, match=r"pip install 'uss-slam\[crf\]'"):
        OnnxSegmenter(path, crf=True)
    assert OnnxSegmenter(path).crf is None  # without crf it is never imported


def _slam(seq: Path, model: Path, out: Path, *extra: str) -> dict:
    cfg = slam_run_config(
        seq, out, "segmenter=onnx", f"segmenter.path={model}", "filters=[semantic]", *extra
    )
    run(cfg)
    return json.loads((out / "metrics.json").read_text())


def test_uss_slam_reports_the_crf_time(synthetic_sequence, tmp_path: Path) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=8, size=(160, 120))
    model = tiny_model(tmp_path / "m.onnx", _metadata(), bias=256.0)
    off = _slam(seq, model, tmp_path / "off")
    on = _slam(seq, model, tmp_path / "on", "segmenter.crf=true")
    assert off["settings"]["segmenter"]["crf"] is False
    assert not any(k.startswith("segmentation.") for k in off["timing_ms"])
    assert on["timing_ms"]["segmentation.crf"] > 0
    assert on["timing_ms"]["segmentation.crf"] <= on["timing_ms"]["segmentation"]
    assert "segmentation.crf" in on["cpu_ms"]
    report = (tmp_path / "on" / "report.md").read_text()
    assert "| segmentation.crf |" in report
    # Bias 256: background everywhere before and after the CRF, the same trajectory.
    off_traj = (tmp_path / "off" / "trajectory.txt").read_bytes()
    assert off_traj == (tmp_path / "on" / "trajectory.txt").read_bytes()

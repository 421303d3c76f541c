"""The ONNX segmenter runtime (``slam_eval/segmenters/onnx.py``): contract checks, class mapping, output
size, providers, ``uss-slam segmenter=onnx``; parity with the PyTorch checkpoint.

The tiny models are built with ``onnx.helper`` (no torch): logits = (128, R, G, B) per pixel, so
the label of a pixel is 0 where every channel is below 128 (ties go to the first index, as
ArgMax), else the index of its largest channel among R, G, B (+1).
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto
from shared_helpers import colour_labels as expected_labels
from shared_helpers import colour_model as tiny_model
from shared_helpers import compose_slam_eval, segmenter_props, slam_run_config

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.onnx_contract import KEY_CLASS_NAMES
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter, resolve_providers

REPO = Path(__file__).resolve().parents[3]


def _metadata(class_names=CLASS_NAMES) -> dict[str, str]:
    return segmenter_props(class_names)


def _random_rgb(h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def test_labels_at_frame_size(tmp_path: Path) -> None:
    seg = OnnxSegmenter(tiny_model(tmp_path / "m.onnx", _metadata()))
    for h, w in ((24, 32), (37, 53)):  # dynamic H, W; odd sizes
        rgb = _random_rgb(h, w, seed=h)
        labels = seg.infer(rgb)
        assert labels.shape == (h, w) and labels.dtype == np.uint8
        np.testing.assert_array_equal(labels, expected_labels(rgb))
    assert seg.name == "onnx:m.onnx" and seg.providers == ["CPUExecutionProvider"]
    assert seg.dynamic_classes == ("person",) and seg.metadata.head == "main"


def test_model_without_metadata_is_refused(tmp_path: Path) -> None:
    path = tiny_model(tmp_path / "plain.onnx", None)
    with pytest.raises(DataFormatError) as info:
        OnnxSegmenter(path)
    message = str(info.value)
    assert str(path) in message and "uss_slam.format" in message
    assert "uss_slam.class_names" in message and "uss-export" in message


def test_missing_single_key_is_named(tmp_path: Path) -> None:
    props = _metadata()
    del props["uss_slam.checkpoint_sha256"]
    path = tiny_model(tmp_path / "m.onnx", props)
    with pytest.raises(DataFormatError, match=r"lacks uss_slam\.checkpoint_sha256 \("):
        OnnxSegmenter(path)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"input_type": TensorProto.FLOAT}, r"input 'image' is tensor\(float\)"),
        ({"input_shape": ("N", 3, "H", "W")}, r"expected tensor\(uint8\) of shape \(N, H, W, 3\)"),
        ({"input_shape": ("N", 24, 32, 3)}, r"fixed height/width \[24, 32\]"),
    ],
)
def test_wrong_input_contract_is_refused(tmp_path: Path, kwargs: dict, match: str) -> None:
    path = tmp_path / "m.onnx"
    if kwargs.get("input_type") == TensorProto.FLOAT:
        # the Cast node accepts float input too: a valid graph with the wrong input dtype
        tiny_model(path, _metadata(), **kwargs)
    else:
        model = onnx.load(str(tiny_model(path, _metadata())))
        dims = model.graph.input[0].type.tensor_type.shape.dim
        for dim, value in zip(dims, kwargs["input_shape"], strict=True):
            dim.Clear()
            if isinstance(value, int):
                dim.dim_value = value
            else:
                dim.dim_param = value
        onnx.save(model, str(path))
    with pytest.raises(DataFormatError, match=match) as info:
        OnnxSegmenter(path)
    assert str(path) in str(info.value)


def test_wrong_layout_metadata_is_refused(tmp_path: Path) -> None:
    props = {**_metadata(), "uss_slam.input_layout": "NCHW"}
    path = tiny_model(tmp_path / "m.onnx", props)
    with pytest.raises(DataFormatError, match=r"uss_slam\.input_layout is 'NCHW', expected 'NHWC'"):
        OnnxSegmenter(path)


def test_missing_labels_output_is_refused(tmp_path: Path) -> None:
    path = tiny_model(tmp_path / "m.onnx", _metadata())
    model = onnx.load(str(path))
    model.graph.output.pop()  # only `logits` left
    onnx.save(model, str(path))
    with pytest.raises(DataFormatError, match=r"expected an output 'labels'") as info:
        OnnxSegmenter(path)
    assert str(path) in str(info.value)


def test_logits_channels_must_match_the_class_list(tmp_path: Path) -> None:
    """Metadata listing 3 classes for a model with 4 logit channels: refused when the graph
    declares the 4 (at load), else on the first frame, whatever mode reads the outputs."""
    three = _metadata(CLASS_NAMES[:3])
    message = (
        r"output 'logits' has 4 channels but uss_slam.class_names lists 3 classes "
        r"\(background, person, chair\); the model and its metadata disagree"
    )
    declared = tiny_model(tmp_path / "declared.onnx", three)
    with pytest.raises(DataFormatError, match=message) as info:
        OnnxSegmenter(declared)
    assert str(info.value).startswith(f"{declared}: ")
    hidden = tiny_model(tmp_path / "hidden.onnx", three, logits_channels="C")
    dark = np.zeros((12, 16, 3), np.uint8)  # every label 0: a valid class id
    for kwargs in ({}, {"threshold": 0.3}):
        seg = OnnxSegmenter(hidden, **kwargs)  # the shape does not say: loads
        with pytest.raises(DataFormatError, match=message) as info:
            seg.infer(dark)
        assert str(info.value).startswith(f"{hidden}: ")
    ok = OnnxSegmenter(tiny_model(tmp_path / "ok.onnx", _metadata(), logits_channels="C"))
    np.testing.assert_array_equal(ok.infer(dark), 0)


def test_label_ids_must_be_classes_of_the_metadata(tmp_path: Path) -> None:
    """A model whose labels hold class id 7 (blue pixels) while its metadata lists 4 classes:
    refused on the frame that first holds it, not only on the first frame; also when its
    class order differs from the project's (where a lookup table would have hidden it)."""
    dark = np.zeros((12, 16, 3), np.uint8)
    blue = dark.copy()
    blue[3:5, 4:9, 2] = 250
    for order in (CLASS_NAMES, ("background", "monitor", "person", "chair")):
        path = tiny_model(tmp_path / "m.onnx", _metadata(order), label_map=(0, 1, 2, 7))
        seg = OnnxSegmenter(path)
        np.testing.assert_array_equal(seg.infer(dark), 0)  # ids 0 only: fine
        with pytest.raises(DataFormatError) as info:
            seg.infer(blue)
        assert str(info.value) == (
            f"{path}: output 'labels' holds class id 7, but uss_slam.class_names lists 4 "
            f"classes (ids 0..3: {', '.join(order)}); the model and its metadata disagree"
        )


def test_threshold_needs_the_logits_output(tmp_path: Path) -> None:
    path = tiny_model(tmp_path / "m.onnx", _metadata())
    model = onnx.load(str(path))
    del model.graph.output[0]  # only `labels` left: enough for argmax, not for a threshold
    onnx.save(model, str(path))
    assert OnnxSegmenter(path).threshold is None
    with pytest.raises(DataFormatError, match=r"segmenter.threshold needs the model's 'logits'"):
        OnnxSegmenter(path, threshold=0.3)


def test_not_an_onnx_file_names_it(tmp_path: Path) -> None:
    path = tmp_path / "junk.onnx"
    path.write_bytes(b"not a model")
    with pytest.raises(DataFormatError, match="is not an ONNX protobuf") as info:
        OnnxSegmenter(path)
    assert str(path) in str(info.value)
    with pytest.raises(UssSlamError, match="segmenter.path=.*absent.onnx: does not exist"):
        OnnxSegmenter(tmp_path / "absent.onnx")


def test_class_names_map_to_project_ids_by_name(tmp_path: Path) -> None:
    order = ("background", "monitor", "person", "chair")  # model index -> name
    seg = OnnxSegmenter(tiny_model(tmp_path / "m.onnx", _metadata(order)))
    rgb = _random_rgb(20, 30)
    model_ids = expected_labels(rgb)
    project = np.array([CLASS_NAMES.index(n) for n in order], np.uint8)
    np.testing.assert_array_equal(seg.infer(rgb), project[model_ids])
    assert set(np.unique(model_ids)) == {0, 1, 2, 3}  # every mapping entry was exercised


def _near_tie_rgb(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Channels within a few units of the background logit 128: graded softmax probabilities."""
    return np.random.default_rng(seed).integers(124, 133, (h, w, 3), dtype=np.uint8)


def _threshold_reference(rgb: np.ndarray, threshold: float, person: int) -> np.ndarray:
    """Model indices: ``person`` where its softmax probability >= threshold, else the most
    probable other index (first on ties, as argmax)."""
    logits = np.concatenate([np.full(rgb.shape[:2] + (1,), 128.0), rgb.astype(np.float64)], 2)
    prob = np.exp(logits) / np.exp(logits).sum(axis=2, keepdims=True)
    others = [c for c in range(4) if c != person]
    labels = np.array(others)[np.argmax(prob[..., others], axis=2)]
    return np.where(prob[..., person] >= threshold, person, labels).astype(np.uint8)


@pytest.mark.parametrize("threshold", [0.1, 0.3, 0.5, 0.8])
def test_threshold_on_the_person_probability(tmp_path: Path, threshold: float) -> None:
    path = tiny_model(tmp_path / "m.onnx", _metadata())
    rgb = _near_tie_rgb(40, 50)
    seg = OnnxSegmenter(path, threshold=threshold)
    labels = seg.infer(rgb)
    np.testing.assert_array_equal(labels, _threshold_reference(rgb, threshold, person=1))
    person = labels == CLASS_NAMES.index("person")
    argmax_person = OnnxSegmenter(path).infer(rgb) == CLASS_NAMES.index("person")
    assert 0 < person.sum() < person.size  # graded: the threshold decides some pixels
    if threshold < 0.5:  # a lower threshold keeps every argmax person pixel and adds others
        assert (person >= argmax_person).all() and person.sum() > argmax_person.sum()
    else:
        assert (person <= argmax_person).all()
    assert "threshold=" in repr(seg)


def test_threshold_maps_model_classes_by_name(tmp_path: Path) -> None:
    order = ("background", "monitor", "person", "chair")  # person is model index 2
    seg = OnnxSegmenter(tiny_model(tmp_path / "m.onnx", _metadata(order)), threshold=0.3)
    rgb = _near_tie_rgb(30, 30, seed=1)
    project = np.array([CLASS_NAMES.index(n) for n in order], np.uint8)
    np.testing.assert_array_equal(seg.infer(rgb), project[_threshold_reference(rgb, 0.3, 2)])


@pytest.mark.parametrize("bad", [0, 0.0, 1, 1.5, -0.2, True, "0.3"])
def test_bad_threshold_is_refused(tmp_path: Path, bad: object) -> None:
    path = tiny_model(tmp_path / "m.onnx", _metadata())
    with pytest.raises(
        UssSlamError, match=r"segmenter.threshold must be a probability in \(0, 1\)"
    ):
        OnnxSegmenter(path, threshold=bad)


def test_unknown_class_name_is_refused(tmp_path: Path) -> None:
    props = _metadata(("background", "person", "chair", "sofa"))
    path = tiny_model(tmp_path / "m.onnx", props)
    with pytest.raises(DataFormatError, match=r"\['sofa'\] of the model are not project classes"):
        OnnxSegmenter(path)
    assert KEY_CLASS_NAMES in props


def test_bad_image_is_refused(tmp_path: Path) -> None:
    seg = OnnxSegmenter(tiny_model(tmp_path / "m.onnx", _metadata()))
    with pytest.raises(UssSlamError, match=r"expected an \(H, W, 3\) uint8 RGB image"):
        seg.infer(np.zeros((8, 8), np.uint8))
    with pytest.raises(UssSlamError, match="dtype float32"):
        seg.infer(np.zeros((8, 8, 3), np.float32))


def test_providers_and_threads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert resolve_providers(None) == ["CPUExecutionProvider"]
    assert resolve_providers("cpu") == ["CPUExecutionProvider"]
    assert resolve_providers(["CPUExecutionProvider"]) == ["CPUExecutionProvider"]
    import onnxruntime as ort

    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CPUExecutionProvider"])
    assert resolve_providers("auto") == ["CPUExecutionProvider"]
    with pytest.raises(UssSlamError, match="CUDAExecutionProvider not available"):
        resolve_providers("cuda")
    monkeypatch.setattr(
        ort, "get_available_providers", lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"]
    )
    assert resolve_providers("auto") == ["CUDAExecutionProvider", "CPUExecutionProvider"]
    assert resolve_providers("cuda") == ["CUDAExecutionProvider", "CPUExecutionProvider"]
    monkeypatch.undo()
    path = tiny_model(tmp_path / "m.onnx", _metadata())
    with pytest.raises(UssSlamError, match="threads must be a whole number in 1.."):
        OnnxSegmenter(path, threads=0)
    seg = OnnxSegmenter(path, threads=1, providers="auto")
    assert seg.threads == 1 and "CPUExecutionProvider" in seg.providers


def test_concurrent_infer_calls_agree(tmp_path: Path) -> None:
    """The pipeline calls infer() from several prefetch threads on one segmenter."""
    seg = OnnxSegmenter(tiny_model(tmp_path / "m.onnx", _metadata()), threads=1)
    images = [_random_rgb(48, 64, seed=s) for s in range(8)]
    results: dict[int, np.ndarray] = {}

    def work(k: int) -> None:
        for _ in range(5):
            results[k] = seg.infer(images[k])

    threads = [threading.Thread(target=work, args=(k,)) for k in range(len(images))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for k, rgb in enumerate(images):
        np.testing.assert_array_equal(results[k], expected_labels(rgb))


def test_config_composes() -> None:
    cfg = compose_slam_eval(["sequence.path=/x", "segmenter=onnx", "segmenter.path=exports/x.onnx"])
    assert cfg.segmenter._target_ == "uss_slam.slam_eval.segmenters.onnx.OnnxSegmenter"
    assert cfg.segmenter.path == "exports/x.onnx"
    assert cfg.segmenter.threads == 1 and cfg.segmenter.providers == "cpu"
    assert cfg.segmenter.threshold is None  # the model's argmax unless asked


def test_uss_slam_runs_an_onnx_segmenter(synthetic_sequence, tmp_path: Path) -> None:
    """``uss-slam segmenter=onnx``: every frame segmented by the model; its labels filter.

    With bias 256 the model labels every pixel background (0): the semantic filter drops nothing
    and the run equals the unfiltered one's keypoint counts."""
    seq = synthetic_sequence(preset="walking_xyz", frames=12, size=(160, 120))
    model = tiny_model(tmp_path / "bg.onnx", _metadata(), bias=256.0)
    out = tmp_path / "run"
    cfg = slam_run_config(
        seq, out, "segmenter=onnx", f"segmenter.path={model}", "filters=[semantic]"
    )
    data = run(cfg)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["segmenter"] == "onnx:bg.onnx" == data["segmenter"]
    assert metrics["frames"] == 12
    assert metrics["segmentation"]["frames_segmented"] == 12
    assert metrics["keypoints"]["dropped"]["semantic"] == 0
    assert metrics["keypoints"]["kept"] == metrics["keypoints"]["extracted"]
    assert metrics["settings"]["segmenter"]["path"] == str(model)


def test_uss_slam_reports_a_bad_model_in_one_line(tmp_path: Path) -> None:
    import subprocess
    import sys

    plain = tiny_model(tmp_path / "plain.onnx", None)
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "uss_slam.slam_eval.run",
            f"sequence.path={tmp_path}",
            "segmenter=onnx",
            f"segmenter.path={plain}",
            f"out_dir={tmp_path / 'out'}",
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert lines[-1].startswith(
        f"uss-slam: error: segmenter.path={plain}: not a uss-slam segmenter"
    )


@pytest.mark.slow  # torch import + export + verification: ~15 s on a quiet 2-core machine
def test_output_equals_the_checkpoints_pytorch_argmax(synthetic_sequence, tmp_path: Path) -> None:
    """Checkpoint (as uss-train writes it) -> export_checkpoint -> OnnxSegmenter, against the
    checkpoint's own PyTorch segmenter on a synthetic target frame (this test imports torch; the
    runtime does not)."""
    import torch
    import torch.nn.functional as F
    import yaml

    from uss_slam.export import export_checkpoint
    from uss_slam.models import DeepLabV2
    from uss_slam.slam_eval.sequence import TumSequence

    torch.manual_seed(3)
    net = DeepLabV2(4, "resnet_small", freeze_bn=False).eval()
    run_dir = tmp_path / "run"
    (run_dir / ".hydra").mkdir(parents=True)
    (run_dir / "checkpoints").mkdir()
    net_cfg = yaml.safe_load(
        (REPO / "configs" / "model" / "net" / "deeplab_small.yaml").read_text()
    )
    config = {"run_name": "parity", "model": {"net": net_cfg}}
    (run_dir / ".hydra" / "config.yaml").write_text(yaml.safe_dump(config))
    ckpt = run_dir / "checkpoints" / "last.ckpt"
    state = {f"segmenter.{k}": v for k, v in net.state_dict().items()}
    torch.save({"state_dict": state, "hyper_parameters": {"class_names": list(CLASS_NAMES)}}, ckpt)

    result = export_checkpoint(ckpt, tmp_path / "exports" / "parity.onnx")
    seg = OnnxSegmenter(result.path, threads=2)
    assert seg.metadata.experiment == "parity"

    seq = TumSequence(str(synthetic_sequence(frames=8, size=(320, 240))))
    rgb = seq.load(5).rgb  # a size the export was neither traced nor verified at
    labels = seg.infer(rgb)

    x = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    with torch.no_grad():
        out = net((x - mean) / std).main
        logits = F.interpolate(out, size=rgb.shape[:2], mode="bilinear", align_corners=True)[0]
    expected = logits.argmax(0).numpy().astype(np.uint8)
    top2 = torch.topk(logits, 2, dim=0).values.numpy()
    clear = (top2[0] - top2[1]) > 1e-4  # pixels whose argmax is not a numerical tie
    assert labels.shape == (240, 320) and clear.mean() > 0.999
    np.testing.assert_array_equal(labels[clear], expected[clear])
    assert len(np.unique(expected)) >= 2  # the frame exercises more than one class


def test_repeats_segment_each_frame_once_and_report_the_time_of_repeat_zero(
    synthetic_sequence, tmp_path: Path, monkeypatch
) -> None:
    """``slam.repeats=3``: the model runs once per frame (repeat 0); the later repeats reuse its
    labels and give the trajectories they gave when they segmented again; the folder's timing
    figures are repeat 0's."""
    seq = synthetic_sequence(preset="walking_xyz", frames=12, size=(160, 120))
    model = tiny_model(tmp_path / "m.onnx", _metadata())
    calls: list[int] = []
    infer = OnnxSegmenter.infer

    def counted(self, rgb):
        calls.append(1)
        return infer(self, rgb)

    monkeypatch.setattr(OnnxSegmenter, "infer", counted)
    args = ("segmenter=onnx", f"segmenter.path={model}", "filters=[semantic]", "slam.repeats=3")
    data = {}
    for reuse in ("true", "false"):
        calls.clear()
        out = tmp_path / reuse
        run(slam_run_config(seq, out, *args, f"slam.reuse_labels={reuse}"))
        data[reuse] = json.loads((out / "metrics.json").read_text())
        assert len(calls) == (12 if reuse == "true" else 36)
        assert data[reuse]["segmentation"]["frames_segmented"] == 12
    kept, again = data["true"], data["false"]
    assert [r["labels_reused"] for r in kept["repeats"]] == [False, True, True]
    assert not any(r["labels_reused"] for r in again["repeats"])
    assert kept["keypoints"]["dropped"]["semantic"] > 0  # the labels did filter
    for a, b in zip(kept["repeats"], again["repeats"], strict=True):
        assert a["ate_rmse"] == b["ate_rmse"] and a["keyframes"] == b["keyframes"]
        assert (tmp_path / "true" / a["trajectory"]).read_text() == (
            tmp_path / "false" / b["trajectory"]
        ).read_text()
    assert kept["timing_repeat"] == 0 and kept["fps"] == kept["repeats"][0]["fps"]
    assert again["timing_repeat"] == again["median_repeat"]
    assert again["fps"] == again["repeats"][again["median_repeat"]]["fps"]
    report = (tmp_path / "true" / "report.md").read_text()
    assert "The time per frame is repeat 0's" in report
    assert "repeat 0's" not in (tmp_path / "false" / "report.md").read_text()


def test_kept_labels_are_read_only_and_reused_calls_run_no_stage() -> None:
    from uss_slam.slam_eval.segmenters.base import (
        LabelsOnce,
        LabelsSegmenter,
        NoSegmenter,
        worth_keeping,
    )
    from uss_slam.slam_eval.sequence import Frame

    class Timed:
        name, needs_labels = "timed", False
        runs = 0

        def segment(self, frame):
            self.runs += 1
            return np.full(frame.gray.shape, frame.index, np.uint8)

        def stage_times(self):
            return {"crf": (0.5, 0.4)}

    inner = Timed()
    once = LabelsOnce(inner)
    rgb = np.zeros((4, 6, 3), np.uint8)
    frames = [Frame(i, 0.1 * i, rgb, rgb[..., 0], np.zeros((4, 6), np.float32)) for i in (0, 1)]
    first = once.segment(frames[1])
    assert once.stage_times() == {"crf": (0.5, 0.4)}
    again = once.segment(frames[1])
    assert again is first and inner.runs == 1 and once.stage_times() == {}
    with pytest.raises(ValueError, match="read-only"):
        again[0, 0] = 7
    assert once.segment(frames[0])[0, 0] == 0 and inner.runs == 2
    assert once.name == "timed" and not once.needs_labels
    once.forget()
    once.segment(frames[1])
    assert inner.runs == 3  # forgotten: segmented again
    assert worth_keeping(inner)
    assert not worth_keeping(NoSegmenter()) and not worth_keeping(LabelsSegmenter())


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (b"", "is empty (0 bytes)"),
        (b"hello\n", "is not an ONNX protobuf (truncated, or another format)"),
        (b"\x08\x07\x12\x04onnx", "holds no ONNX graph"),
    ],
)
def test_a_file_that_is_no_whole_onnx_model_is_one_line_in_the_projects_words(
    content: bytes, says: str, tmp_path: Path
) -> None:
    """An empty, a text or a truncated ``.onnx``: the line says what the file is, without
    onnxruntime's ``[ONNXRuntimeError] : 7 : INVALID_PROTOBUF`` text."""
    path = tmp_path / "model.onnx"
    path.write_bytes(content)
    with pytest.raises(DataFormatError) as raised:
        OnnxSegmenter(path)
    assert str(raised.value) == f"{path}: {says}; expected an ONNX model written by uss-export"

"""`uss-export` and the ONNX contract: a tiny random DeepLab-v2 exported and verified at two
sizes, metadata round trip, dynamic batch / height / width, failed verification leaves earlier
files intact, checkpoints with their run config, and the Hydra app end to end."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
import torch.nn.functional as F
import yaml
from shared_helpers import NET_YAML, data_overrides, segmenter_metadata
from shared_helpers import fake_run as _fake_run
from shared_helpers import tiny_net as _tiny_net

import uss_slam.export as export
from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.onnx_contract import (
    KEY_DYNAMIC_CLASSES,
    KEY_FORMAT,
    KEY_HEAD,
    ONNX_METADATA_KEYS,
    SegmenterMetadata,
)
from uss_slam.export import (
    ExportVerificationError,
    SegmenterExport,
    export_checkpoint,
    export_segmenter,
    load_checkpoint,
    verification_images,
)
from uss_slam.export import cli as export_cli
from uss_slam.export import verify as export_verify
from uss_slam.models import DeepLabV2


def _metadata(head: str = "main") -> SegmenterMetadata:
    return segmenter_metadata(CLASS_NAMES, head=head, experiment="unit")


def _eager(net: DeepLabV2, images: np.ndarray, head: str = "main") -> tuple[np.ndarray, np.ndarray]:
    """Reference computed without the export wrapper: normalise, NCHW, head, upsample."""
    x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    with torch.no_grad():
        out = getattr(net((x - mean) / std), head)
        logits = F.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=True)
    return logits.numpy(), logits.argmax(1).numpy().astype(np.uint8)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[DeepLabV2, export.ExportResult]:
    net = _tiny_net()
    out = tmp_path_factory.mktemp("export") / "tiny.onnx"
    return net, export_segmenter(net, out, _metadata(), trace_size=(65, 81), verify_size=(49, 57))


# ---------------------------------------------------------------------------- contract module


def test_contract_module_is_torch_free() -> None:
    code = "import sys, uss_slam.core.onnx_contract; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_metadata_props_round_trip_and_refusals() -> None:
    meta = _metadata()
    props = meta.to_props()
    assert set(props) == set(ONNX_METADATA_KEYS)
    assert all(isinstance(v, str) for v in props.values())
    assert SegmenterMetadata.from_props(props) == meta
    assert meta.dynamic_class_ids == (1,)
    for key in (KEY_FORMAT, KEY_HEAD):
        broken = {k: v for k, v in props.items() if k != key}
        with pytest.raises(DataFormatError, match=f"m.onnx: .*lacks {key}"):
            SegmenterMetadata.from_props(broken, "m.onnx")
    with pytest.raises(DataFormatError, match="reads '1'"):
        SegmenterMetadata.from_props({**props, KEY_FORMAT: "2"}, "m.onnx")
    with pytest.raises(DataFormatError, match="not in"):
        SegmenterMetadata.from_props({**props, KEY_DYNAMIC_CLASSES: '["car"]'}, "m.onnx")
    with pytest.raises(DataFormatError, match="not JSON"):
        SegmenterMetadata.from_props({**props, KEY_DYNAMIC_CLASSES: "[person"}, "m.onnx")


# ---------------------------------------------------------------------------- export + verify


@pytest.mark.parametrize(
    ("trace_size", "verify_size", "batch"), [((65, 81), (120, 160), 2), ((97, 129), (50, 71), 1)]
)
def test_export_verifies_at_another_size(
    trace_size: tuple[int, int], verify_size: tuple[int, int], batch: int, tmp_path: Path
) -> None:
    net = _tiny_net()
    result = export_segmenter(
        net, tmp_path / "m.onnx", _metadata(), trace_size=trace_size, verify_size=verify_size
    )
    report = json.loads(result.verify_path.read_text())
    assert result.verify_path == tmp_path / "m.verify.json"
    assert report == result.verify
    assert report["ok"] is True and report["checker"] == "ok"
    assert report["trace_size"] == list(trace_size) and report["verify_size"] == list(verify_size)
    assert report["logits_shape"] == [export_verify.VERIFY_BATCH, 4, *verify_size]
    assert report["max_abs_logit_diff"] <= 1e-4 and report["label_agreement"] >= 0.999
    assert len(report["classes_present"]) >= 2  # the check compares more than one class
    assert set(report["versions"]) == {"uss_slam", "torch", "onnx", "onnxruntime"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.onnx", "m.verify.json"]
    # Independently of the verification: onnxruntime at a third size equals the reference.
    images = verification_images((41, 66), batch=batch, seed=5)
    logits, labels = ort.InferenceSession(str(result.path)).run(None, {"image": images})
    ref_logits, ref_labels = _eager(net, images)
    assert np.abs(logits - ref_logits).max() <= 1e-4
    assert (labels == ref_labels).mean() >= 0.999


def test_graph_follows_the_contract(exported: tuple[DeepLabV2, export.ExportResult]) -> None:
    _, result = exported
    model = onnx.load(str(result.path))
    (inp,) = model.graph.input
    assert inp.name == "image"
    assert inp.type.tensor_type.elem_type == onnx.TensorProto.UINT8
    dims = inp.type.tensor_type.shape.dim
    assert [d.dim_param or d.dim_value for d in dims] == ["N", "H", "W", 3]
    outputs = {o.name: o.type.tensor_type for o in model.graph.output}
    assert list(outputs) == ["logits", "labels"]
    assert outputs["logits"].elem_type == onnx.TensorProto.FLOAT
    assert outputs["labels"].elem_type == onnx.TensorProto.UINT8


def test_metadata_round_trip(exported: tuple[DeepLabV2, export.ExportResult]) -> None:
    _, result = exported
    model = onnx.load(str(result.path))
    props = {p.key: p.value for p in model.metadata_props}
    assert SegmenterMetadata.from_props(props, result.path) == _metadata()
    session_props = ort.InferenceSession(str(result.path)).get_modelmeta().custom_metadata_map
    assert SegmenterMetadata.from_props(session_props, result.path) == result.metadata


def test_dynamic_batch_height_width(exported: tuple[DeepLabV2, export.ExportResult]) -> None:
    net, result = exported
    session = ort.InferenceSession(str(result.path))
    for shape, seed in (((1, 50, 70), 1), ((2, 33, 47), 2), ((3, 120, 96), 3)):
        images = verification_images(shape[1:], batch=shape[0], seed=seed)
        logits, labels = session.run(["logits", "labels"], {"image": images})
        assert logits.shape == (shape[0], 4, *shape[1:]) and logits.dtype == np.float32
        assert labels.shape == shape and labels.dtype == np.uint8
        np.testing.assert_array_equal(labels, logits.argmax(1))
        ref_logits, _ = _eager(net, images)
        assert np.abs(logits - ref_logits).max() <= 1e-4


def test_aux_head(tmp_path: Path) -> None:
    net = _tiny_net(seed=3)
    result = export_segmenter(net, tmp_path / "aux.onnx", _metadata("aux"))
    images = verification_images((64, 80), batch=1, seed=4)
    logits, _ = ort.InferenceSession(str(result.path)).run(None, {"image": images})
    ref_aux, _ = _eager(net, images, "aux")
    ref_main, _ = _eager(net, images, "main")
    assert np.abs(logits - ref_aux).max() <= 1e-4
    assert np.abs(logits - ref_main).max() > 1e-3


def test_failed_verification_keeps_earlier_files(
    exported: tuple[DeepLabV2, export.ExportResult],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    net, _ = exported
    good = export_segmenter(net, tmp_path / "m.onnx", _metadata())
    before = {p.name: p.read_bytes() for p in (good.path, good.verify_path)}
    monkeypatch.setattr(export_verify, "MAX_LOGIT_DIFF", -1.0)
    monkeypatch.setattr(export_verify, "MAX_RELATIVE_LOGIT_DIFF", -1.0)
    with pytest.raises(ExportVerificationError, match="failed verification"):
        export_segmenter(_tiny_net(seed=9), tmp_path / "m.onnx", _metadata())
    assert {p.name: p.read_bytes() for p in (good.path, good.verify_path)} == before
    failed = json.loads((tmp_path / "m.verify.failed.json").read_text())
    assert failed["ok"] is False and failed["max_logit_diff_allowed"] < 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "m.onnx",
        "m.verify.failed.json",
        "m.verify.json",
    ]


def test_export_refuses_equal_trace_and_verify_size(tmp_path: Path) -> None:
    with pytest.raises(UssSlamError, match="must differ"):
        export_segmenter(_tiny_net(), tmp_path / "m.onnx", _metadata(), verify_size=(97, 129))
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------------- checkpoints


def test_load_checkpoint_uses_the_run_config(tmp_path: Path) -> None:
    net = _tiny_net(seed=5)
    ckpt = _fake_run(tmp_path / "run", net)
    loaded = load_checkpoint(ckpt)
    assert loaded.experiment == "fake" and loaded.iteration == 7
    assert loaded.class_names == CLASS_NAMES and len(loaded.sha256) == 64
    own = net.state_dict()
    for key, value in loaded.segmenter.state_dict().items():
        assert torch.equal(value, own[key]), key
    assert not loaded.segmenter.training


def test_checkpoint_without_run_config_needs_net_config(tmp_path: Path) -> None:
    ckpt = _fake_run(tmp_path / "run", _tiny_net())
    moved = tmp_path / "moved.ckpt"
    ckpt.rename(moved)
    with pytest.raises(DataFormatError, match=r"config\.yaml: no training config"):
        load_checkpoint(moved)
    assert load_checkpoint(moved, NET_YAML).experiment == "moved"
    wrong = yaml.safe_load(NET_YAML.read_text()) | {"backbone": "resnet50"}
    with pytest.raises(DataFormatError, match="moved.ckpt: segmenter weights do not fit"):
        load_checkpoint(moved, wrong)


def test_a_run_config_edited_by_hand_is_one_line_naming_its_file_and_key(tmp_path: Path) -> None:
    """A value of the wrong type in the run's ``.hydra/config.yaml`` is the schema's line under
    the file's name, not the network's ``TypeError``; YAML that does not parse names it too."""
    ckpt = _fake_run(tmp_path / "run", _tiny_net())
    config = tmp_path / "run" / ".hydra" / "config.yaml"
    text = config.read_text()
    config.write_text(text.replace("num_classes: 4", "num_classes: four"))
    with pytest.raises(
        DataFormatError, match=r"config\.yaml: model\.net\.num_classes: expected an"
    ):
        load_checkpoint(ckpt)
    config.write_text(text + "\nmodel: [\n")
    with pytest.raises(DataFormatError, match=r"config\.yaml: not a readable YAML file"):
        load_checkpoint(ckpt)


def test_export_checkpoint_records_checkpoint_and_run(tmp_path: Path) -> None:
    net = _tiny_net(seed=6)
    ckpt = _fake_run(tmp_path / "run", net, run_name="demo")
    result = export_checkpoint(ckpt, tmp_path / "out" / "demo.onnx", head="aux")
    props = ort.InferenceSession(str(result.path)).get_modelmeta().custom_metadata_map
    meta = SegmenterMetadata.from_props(props)
    assert meta.experiment == "demo" and meta.head == "aux"
    assert meta.checkpoint_sha256 == hashlib.sha256(ckpt.read_bytes()).hexdigest()
    images = verification_images((45, 61), batch=1, seed=8)
    logits, _ = ort.InferenceSession(str(result.path)).run(None, {"image": images})
    assert np.abs(logits - _eager(net, images, "aux")[0]).max() <= 1e-4
    with pytest.raises(UssSlamError, match="dynamic_classes"):
        export_checkpoint(ckpt, tmp_path / "x.onnx", dynamic_classes=["car"])


def test_cli_failed_verification_exits_nonzero(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    ckpt = _fake_run(tmp_path / "run", _tiny_net())
    monkeypatch.chdir(tmp_path)
    argv = ["uss-export", f"ckpt_path={ckpt}", "out_dir=exports"]
    monkeypatch.setattr(sys, "argv", argv)
    export_cli.main()
    model = tmp_path / "exports" / "fake.onnx"
    before = model.read_bytes()
    assert "wrote exports/fake.onnx" in capsys.readouterr().out
    monkeypatch.setattr(export_verify, "MIN_LABEL_AGREEMENT", 1.5)
    with pytest.raises(SystemExit) as exit_info:
        export_cli.main()
    assert exit_info.value.code == 1
    err = capsys.readouterr().err
    assert err.startswith("uss-export: error: exports/fake.onnx: exported model failed")
    assert model.read_bytes() == before
    assert (tmp_path / "exports" / "fake.verify.failed.json").is_file()


# ---------------------------------------------------------------------------- end to end


@pytest.mark.slow
def test_uss_export_on_a_ci_run(uda_data: dict[str, Path], tmp_path: Path) -> None:
    bin_dir = Path(sys.executable).parent
    run = tmp_path / "run"
    train = [
        str(bin_dir / "uss-train"),
        "experiment=ci",
        *data_overrides(uda_data),
        "logger=none",
        f"hydra.run.dir={run}",
    ]
    result = subprocess.run(train, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    ckpt = run / "checkpoints" / "last.ckpt"
    cmd = [str(bin_dir / "uss-export"), f"ckpt_path={ckpt}", "num_threads=2"]
    result = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    model = tmp_path / "exports" / "ci.onnx"
    report = json.loads((tmp_path / "exports" / "ci.verify.json").read_text())
    assert report["ok"] is True and report["experiment"] == "ci"
    props = ort.InferenceSession(str(model)).get_modelmeta().custom_metadata_map
    meta = SegmenterMetadata.from_props(props, model)
    assert meta.checkpoint_sha256 == hashlib.sha256(ckpt.read_bytes()).hexdigest()
    # The ONNX model reproduces the checkpoint's segmenter as the trainer built it.
    loaded = load_checkpoint(ckpt)
    images = verification_images((65, 65), batch=1, seed=3)
    logits, _ = ort.InferenceSession(str(model)).run(None, {"image": images})
    with torch.no_grad():
        ref, _ = SegmenterExport(loaded.segmenter)(torch.from_numpy(images))
    assert np.abs(logits - ref.numpy()).max() <= 1e-4
    missing = subprocess.run(
        [str(bin_dir / "uss-export"), f"ckpt_path={tmp_path / 'none.ckpt'}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert missing.returncode == 1
    assert missing.stderr.strip().endswith(
        "none.ckpt: does not exist; expected a uss-train checkpoint (.ckpt)"
    )


def test_int8_model_from_target_frames(
    exported: tuple[DeepLabV2, export.ExportResult],
    synthetic_sequence,
    tmp_path: Path,
) -> None:
    net, _ = exported
    fp32 = export_segmenter(net, tmp_path / "q.onnx", _metadata())
    sequence = synthetic_sequence(frames=8, size=(160, 120), seed=2)
    result = export.add_int8(fp32, sequence, frames=3, threads=1)
    assert result.int8_path == tmp_path / "q.int8.onnx"
    figures = json.loads(result.verify_path.read_text())["int8"]
    assert figures == result.verify["int8"]
    assert figures["calibration_frames"] == 3 and figures["evaluation_frames"] == 3
    assert figures["frame_size"] == [120, 160]
    assert 0.5 <= figures["label_agreement_vs_fp32"] <= 1.0
    assert figures["speedup"] == pytest.approx(figures["fp32_ms"] / figures["int8_ms"], rel=0.02)
    model = onnx.load(str(result.int8_path))
    ops = {node.op_type for node in model.graph.node}
    assert {"QuantizeLinear", "DequantizeLinear", "Resize", "ArgMax"} <= ops
    props = {p.key: p.value for p in model.metadata_props}
    meta = SegmenterMetadata.from_props(props, result.int8_path)
    assert meta.extra == {export.KEY_QUANTIZATION: "int8-static-qdq"}
    images = verification_images((120, 160), batch=2, seed=7)
    logits, labels = ort.InferenceSession(str(result.int8_path)).run(None, {"image": images})
    assert logits.shape == (2, 4, 120, 160) and labels.dtype == np.uint8
    assert sorted(p.name for p in tmp_path.iterdir()) == ["q.int8.onnx", "q.onnx", "q.verify.json"]


def test_int8_refuses_a_folder_without_rgb_list(
    exported: tuple[DeepLabV2, export.ExportResult], tmp_path: Path
) -> None:
    with pytest.raises(DataFormatError, match=r"rgb\.txt: calibration.root must be"):
        export.add_int8(exported[1], tmp_path)


def test_tolerances_are_parameters(tmp_path: Path) -> None:
    with pytest.raises(ExportVerificationError, match=r"<= -1\.0\?"):
        export_segmenter(_tiny_net(), tmp_path / "m.onnx", _metadata(), max_logit_diff=-1.0)
    failed = json.loads((tmp_path / "m.verify.failed.json").read_text())
    assert failed["max_logit_diff_allowed"] == -1.0 and failed["min_label_agreement"] == 0.999
    assert failed["label_agreement"] >= 0.999  # only the tolerance made it fail
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.verify.failed.json"]


def test_default_logit_tolerance_grows_with_the_logits(
    exported: tuple[DeepLabV2, export.ExportResult], tmp_path: Path
) -> None:
    """Scaling the classifier by 1000 multiplies the logits (and float32 reordering errors) by
    1000: the default tolerance follows the largest |logit|; an explicit one stays absolute."""
    net = _tiny_net(seed=3)
    with torch.no_grad():
        for head in (net.main, net.aux):
            for p in head.parameters():
                p.mul_(1000.0)
    result = export_segmenter(net, tmp_path / "big.onnx", _metadata())
    report = json.loads(result.verify_path.read_text())
    assert report["max_abs_logit"] > 10.0
    assert report["max_logit_diff_allowed"] == pytest.approx(
        max(
            export_verify.MAX_LOGIT_DIFF,
            export_verify.MAX_RELATIVE_LOGIT_DIFF * report["max_abs_logit"],
        )
    )
    with pytest.raises(ExportVerificationError, match="failed verification"):
        export_segmenter(net, tmp_path / "strict.onnx", _metadata(), max_logit_diff=1e-9)


def test_an_export_frame_size_has_a_bound() -> None:
    from uss_slam.export.onnx import check_size

    assert check_size("verify_size", [120, 160]) == (120, 160)
    with pytest.raises(
        UssSlamError, match=r"^verify_size must be \[H, W\], each side at most 8192"
    ):
        check_size("verify_size", [100000, 100000])

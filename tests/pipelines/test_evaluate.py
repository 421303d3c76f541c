"""``uss-eval``: per-class IoU, mIoU and the dynamic-mask metrics of an ONNX model or a
checkpoint on labelled frames, against answers computed here from the files; one-line errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from pipeline_helpers import colour_model, tiny_run
from shared_helpers import colour_labels

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.core.tum_io import read_file_list
from uss_slam.pipelines import demo, evaluate


def _frames(seq: Path, stride: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rgb, labels) of every ``stride``-th frame, read with OpenCV."""
    files = read_file_list(seq / "rgb.txt")
    out = []
    for k in range(0, len(files), stride):
        rgb = cv2.cvtColor(cv2.imread(str(files.resolve(k))), cv2.COLOR_BGR2RGB)
        labels = cv2.imread(str(seq / "labels" / files.resolve(k).name), cv2.IMREAD_UNCHANGED)
        out.append((rgb, labels))
    return out


def _expected(pairs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, list[tuple]]:
    """Confusion matrix and per-frame person (tp, fp, fn) counted here, plainly."""
    n = len(CLASS_NAMES)
    matrix = np.zeros((n, n), np.int64)
    person = []
    for labels, pred in pairs:
        for t, p in zip(labels.ravel(), pred.ravel(), strict=True):
            if t != 255:
                matrix[t, p] += 1
        valid = labels != 255
        t, p = (labels == 1) & valid, (pred == 1) & valid
        person.append((int((t & p).sum()), int((~t & p).sum()), int((t & ~p).sum())))
    return matrix, person


def test_onnx_model_on_a_sequence(tmp_path: Path, synthetic_sequence, capsys) -> None:
    seq = synthetic_sequence(frames=6, size=(64, 48))
    model = colour_model(tmp_path / "colour.onnx")
    out = tmp_path / "eval"
    code = evaluate.main([str(model), "--sequence", str(seq), "--stride", "2", "--overlays", "2",
                          "--out", str(out)])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    result = json.loads((out / "eval.json").read_text())
    frames = _frames(seq, 2)
    matrix, person = _expected([(labels, colour_labels(rgb)) for rgb, labels in frames])
    assert result["frames"] == 3 and result["classes"] == list(CLASS_NAMES)
    np.testing.assert_array_equal(result["confusion_matrix"], matrix)
    tp, union = np.diag(matrix), matrix.sum(0) + matrix.sum(1) - np.diag(matrix)
    iou = {name: (tp[k] / union[k] if union[k] else None) for k, name in enumerate(CLASS_NAMES)}
    assert result["IoU"] == pytest.approx(iou)
    assert result["mIoU"] == pytest.approx(np.mean([v for v in iou.values() if v is not None]))
    # the dynamic (person) mask: pooled pixels and the paper's per-frame classification
    mask = result["mask"]
    total = sum(labels.size - int((labels == 255).sum()) for _, labels in frames)
    tps, fps, fns = (sum(c[i] for c in person) for i in range(3))
    assert mask["pixels_pooled"]["counts"] == {"TP": tps, "FP": fps, "TN": total - tps - fps - fns,
                                               "FN": fns}  # fmt: skip
    outcome = {"TP": 0, "FP": 0, "TN": 0, "FN": 0}
    for t, f, n in person:
        if t + n:
            outcome["TP" if t / (t + f + n) >= 0.5 else "FN"] += 1
        else:
            outcome["FP" if f else "TN"] += 1
    assert mask["frames"]["counts"] == outcome and result["dynamic_classes"] == ["person"]
    assert result["model"]["kind"] == "onnx" and result["model"]["experiment"] == "colour"
    assert result["data"] == {"source": "sequence", "roots": [str(seq)], "stride": 2}
    # report: printed = eval.md; overlays of the first and last frame, truth | prediction
    md = (out / "eval.md").read_text()
    assert md in printed and "| person |" in md and "| PWC |" in md
    assert f"**mIoU {result['mIoU']:.4f}**" in md
    assert result["overlays"] == [f"overlays/000_{seq.name}_{_stamp(seq, 0)}.png",
                                  f"overlays/001_{seq.name}_{_stamp(seq, 4)}.png"]  # fmt: skip
    for name in result["overlays"]:
        image = cv2.imread(str(out / name))
        assert image.shape == (48, 128, 3)


def _stamp(seq: Path, k: int) -> str:
    return read_file_list(seq / "rgb.txt").resolve(k).stem


def test_same_numbers_as_the_demo_miou_stage(tmp_path: Path, synthetic_sequence) -> None:
    seq = synthetic_sequence(frames=6, size=(64, 48))
    model = colour_model(tmp_path / "colour.onnx")
    result = evaluate.evaluate(model, tmp_path / "eval", sequences=[seq], stride=5)
    scores = demo.miou_scores(seq, {"colour": model}, stride=5)["colour"]
    assert scores["frames"] == result["frames"] == 2
    assert scores["mIoU"] == result["mIoU"] and scores["IoU"] == result["IoU"]


@pytest.mark.parametrize(
    ("model", "says"),
    [
        ({"label_map": (7, 1, 2, 3)}, "output 'labels' holds class id 7, but uss_slam.class_names"),
        (
            {"class_names": ("background", "person", "chair"), "logits_channels": "C"},
            "output 'logits' has 4 channels but uss_slam.class_names lists 3 classes",
        ),
    ],
    ids=["label-not-a-class", "channels-not-the-classes"],
)
def test_every_user_of_a_model_checks_its_outputs_alike(
    tmp_path: Path, synthetic_sequence, model: dict, says: str
) -> None:
    """A model whose outputs disagree with its metadata: uss-eval, the demo's mIoU stage and
    the experiments' segmentation evaluation stop with the same error, naming the model, and
    write nothing (uss-slam's is in tests/test_cli_matrix.py)."""
    from shared_helpers import colour_model as build
    from shared_helpers import segmenter_props

    from uss_slam.core.errors import DataFormatError
    from uss_slam.pipelines.experiments import jobs

    seq = synthetic_sequence(frames=6, size=(64, 48))
    names = model.pop("class_names", CLASS_NAMES)
    path = build(tmp_path / "bad.onnx", segmenter_props(names), **model)
    calls = {
        "uss-eval": lambda: evaluate.evaluate(path, tmp_path / "eval", sequences=[seq]),
        "demo": lambda: demo.miou_scores(seq, {"bad": path}, stride=5),
        "experiments": lambda: jobs.run_segeval(
            tmp_path / "job", {"model": str(path), "sequences": {"s": str(seq)}, "stride": 2}
        ),
    }
    for who, call in calls.items():
        with pytest.raises(DataFormatError) as info:
            call()
        assert str(info.value).startswith(f"{path}: {says}"), (who, str(info.value))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.onnx"]


def test_checkpoint_outputs_are_held_to_its_class_list(tmp_path: Path) -> None:
    """uss-eval runs a checkpoint through the same checks: a checkpoint whose class list is
    shorter than its net's classes is refused on the first frame, naming the file."""
    from uss_slam.core.errors import DataFormatError

    ckpt = tiny_run(tmp_path / "run")
    model = evaluate.CheckpointSegmenter(ckpt)
    rgb = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    assert model.infer(rgb).shape == (24, 32)
    model.class_names = CLASS_NAMES[:3]
    with pytest.raises(DataFormatError, match=r"has 4 channels but uss_slam.class_names lists 3"):
        model.infer(rgb)


def test_checkpoint_on_a_sequence_and_on_the_data_config_val_set(
    tmp_path: Path, synthetic_sequence
) -> None:
    seq = synthetic_sequence(frames=6, size=(64, 48))
    ckpt = tiny_run(tmp_path / "run")
    by_folder = evaluate.evaluate(ckpt, tmp_path / "a", sequences=[seq])
    by_config = evaluate.evaluate(
        ckpt, tmp_path / "b", overrides=[f"data.val.roots=[{seq}]", "data.val.stride=1"]
    )
    assert by_config["data"]["source"] == "data.val"
    assert by_folder["confusion_matrix"] == by_config["confusion_matrix"]
    assert by_folder["model"]["kind"] == "checkpoint" and by_folder["model"]["experiment"] == "tiny"
    # the checkpoint's segmenter run here, plainly: normalise, main head, upsample, argmax
    from uss_slam.export import load_checkpoint

    net = load_checkpoint(ckpt).segmenter.eval()
    mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    pairs = []
    with torch.no_grad():
        for rgb, labels in _frames(seq, 1):
            x = (torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255 - mean) / std
            logits = F.interpolate(net(x).main, size=labels.shape, mode="bilinear",
                                   align_corners=True)  # fmt: skip
            pairs.append((labels, logits.argmax(1)[0].numpy().astype(np.uint8)))
    matrix, _ = _expected(pairs)
    # equal up to pixels whose two best logits tie within float rounding
    diff = np.abs(np.asarray(by_folder["confusion_matrix"]) - matrix).sum()
    assert diff <= 2 * 0.001 * matrix.sum(), diff


@pytest.mark.slow
def test_checkpoint_and_its_export_agree(tmp_path: Path, synthetic_sequence) -> None:
    from uss_slam.export import export_checkpoint

    seq = synthetic_sequence(frames=6, size=(64, 48))
    ckpt = tiny_run(tmp_path / "run")
    onnx = export_checkpoint(ckpt, tmp_path / "tiny.onnx").path
    a = evaluate.evaluate(ckpt, tmp_path / "a", sequences=[seq])
    b = evaluate.evaluate(onnx, tmp_path / "b", sequences=[seq])
    assert b["model"]["checkpoint_sha256"] == a["model"]["sha256"]
    diff = np.abs(np.asarray(a["confusion_matrix"]) - np.asarray(b["confusion_matrix"])).sum()
    assert diff <= 2 * 0.001 * np.sum(a["confusion_matrix"])


def _error(argv: list[str], capsys, code: int = 1) -> str:
    """The one error line (exit code ``code``; 2: argparse's, after its usage lines)."""
    with pytest.raises(SystemExit) as exit_info:
        evaluate.main(argv)
    assert exit_info.value.code == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 or (code == 2 and err[0].startswith("usage:")), err
    return err[-1]


def test_bad_inputs_are_one_line(tmp_path: Path, synthetic_sequence, capsys) -> None:
    seq = synthetic_sequence(frames=6, size=(64, 48))
    model = colour_model(tmp_path / "colour.onnx")
    out = ["--out", str(tmp_path / "out")]
    missing = tmp_path / "none.onnx"
    assert _error([str(missing), "--sequence", str(seq), *out], capsys) == (
        f"uss-eval: error: {missing}: does not exist; expected a uss-train checkpoint (.ckpt) "
        "or an exported model (.onnx)"
    )
    weights = tmp_path / "model.pt"
    weights.write_bytes(b"")
    assert "expected a uss-train checkpoint (.ckpt) or an exported model (.onnx)" in _error(
        [str(weights), "--sequence", str(seq), *out], capsys
    )
    no_labels = tmp_path / "no_labels"
    shutil.copytree(seq, no_labels)
    shutil.rmtree(no_labels / "labels")
    assert "labels" in _error([str(model), "--sequence", str(no_labels), *out], capsys)
    assert "expected a data-config override KEY=VALUE" in _error([str(model), "datareal", *out],
                                                                 capsys)  # fmt: skip
    assert "not both" in _error([str(model), "data=synthetic", "--sequence", str(seq), *out],
                                capsys)  # fmt: skip
    # beside --sequence: a second model, a second value of --dynamic, named (not "not both")
    second = tmp_path / "m2.onnx"
    assert _error([str(model), str(second), "--sequence", str(seq), *out], capsys) == (
        f"uss-eval: error: {str(second)!r}: expected a data-config override KEY=VALUE (e.g. "
        "data=real, paths.data_dir=DIR, data.val.stride=1); two models are compared by "
        "uss-eval compare MODEL MODEL --sequence DIR"
    )
    assert "'chair': expected a data-config override KEY=VALUE" in _error(
        [str(model), "--sequence", str(seq), "--dynamic", "person", "chair", *out], capsys
    )
    assert "argument --overlays: expected an integer >= 0, got '-1'" in _error(
        [str(model), "--sequence", str(seq), "--overlays", "-1", *out], capsys, code=2
    )
    assert "argument --dynamic: expected comma-separated names of background, person, chair, " \
        "monitor, each once, got 'sky'" in _error(
        [str(model), "--sequence", str(seq), "--dynamic", "sky", *out], capsys, code=2
    )  # fmt: skip
    assert "argument --frame-iou: expected a number > 0 and <= 1, got '0'" in _error(
        [str(model), "--sequence", str(seq), "--frame-iou", "0", *out], capsys, code=2
    )
    # a data config that does not compose, and one whose val set is missing: one line each
    assert _error([str(model), "data=nonexistent", *out], capsys).startswith("uss-eval: error: ")
    gone = tmp_path / "gone"
    assert str(gone) in _error([str(model), f"data.val.roots=[{gone}]", *out], capsys)
    assert not (tmp_path / "out").exists()  # nothing written for a bad input


def test_evenly_spaced() -> None:
    assert evaluate.evenly_spaced(3, 10) == [0, 4, 9]  # 0, 4.5 -> 4 (round half to even), 9
    assert evaluate.evenly_spaced(5, 3) == [0, 1, 2]
    assert evaluate.evenly_spaced(0, 3) == [] and evaluate.evenly_spaced(1, 4) == [0]


def test_image_folders_need_no_depth_and_bad_labels_are_named(tmp_path) -> None:
    """A labelled image folder (rgb.txt, rgb/, labels/; no depth) is scored; labels of another
    size, and a folder given twice, are one-line errors naming the file or folder."""
    import cv2
    import numpy as np

    from uss_slam.core.errors import DataFormatError, UssSlamError
    from uss_slam.pipelines.evaluate import sequence_frames
    from uss_slam.synthetic.voc import render_voc_frames

    folder = render_voc_frames(tmp_path / "imgs", images=3, size=(64, 48), seed=1, style="target")
    assert not (folder / "depth.txt").exists()
    source = sequence_frames([folder], stride=1)
    frames = list(source.frames())
    assert source.count == 3 and frames[0].rgb.shape == (48, 64, 3)
    assert frames[0].labels.shape == (48, 64) and frames[0].labels.dtype == np.uint8
    with pytest.raises(UssSlamError, match="given twice"):
        sequence_frames([folder, tmp_path / "imgs"], stride=1)
    bad = sorted((folder / "labels").glob("*.png"))[1]
    cv2.imwrite(str(bad), np.zeros((10, 10), np.uint8))
    with pytest.raises(DataFormatError, match=r"labels are 10x10 but the colour image"):
        list(sequence_frames([folder], stride=1).frames())

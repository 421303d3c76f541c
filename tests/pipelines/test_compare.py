"""``uss-eval compare``: validators, mask agreement and labelled intervals of exported models on a
sequence, against answers computed here from the files; every bad input one line before any work,
and nothing written on failure."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from pipeline_helpers import colour_model
from shared_helpers import colour_labels, segmenter_metadata
from shared_helpers import colour_model as raw_colour_model

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.tum_io import read_file_list
from uss_slam.core.validators import Entropy, InformationMaximization, downsample_maps
from uss_slam.core.verdict import iou_from_matrix
from uss_slam.pipelines.evaluate import main


def _rgbs(seq: Path) -> list[np.ndarray]:
    files = read_file_list(seq / "rgb.txt")
    return [
        cv2.cvtColor(cv2.imread(str(files.resolve(k))), cv2.COLOR_BGR2RGB)
        for k in range(len(files))
    ]


def _softmax(rgb: np.ndarray, bias: float) -> np.ndarray:
    logits = np.concatenate([np.full(rgb.shape[:2] + (1,), bias), rgb.astype(np.float64)], axis=2)
    e = np.exp(logits - logits.max(axis=2, keepdims=True))
    return (e / e.sum(axis=2, keepdims=True)).transpose(2, 0, 1)[None].astype(np.float32)


@pytest.fixture
def models(tmp_path: Path) -> list[Path]:
    return [colour_model(tmp_path / f"{name}.onnx", bias=b)
            for name, b in (("low", 100.0), ("mid", 128.0), ("near", 128.5))]  # fmt: skip


def test_compare_without_labels(tmp_path: Path, synthetic_sequence, models, capsys) -> None:
    seq = synthetic_sequence(frames=6, size=(64, 48))
    out = tmp_path / "report"
    args = [*map(str, models), "--sequence", str(seq), "--out", str(out), "--batch", "4",
            "--validators", "entropy,im,dynamic_share"]  # fmt: skip
    assert main(["compare", *args]) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    result = json.loads((out / "compare.json").read_text())
    rgbs = _rgbs(seq)
    for name, bias in (("low", 100.0), ("mid", 128.0), ("near", 128.5)):
        ent, im = Entropy(), InformationMaximization()
        share = np.mean([(colour_labels(r, bias) == 1).mean() for r in rgbs])
        for rgb in rgbs:
            small = downsample_maps(_softmax(rgb, bias), 160)
            ent.update(small)
            im.update(small)
        got = result["validators"][name]
        assert got["entropy"] == pytest.approx(ent.score(), rel=1e-4, abs=1e-6)
        assert got["im"] == pytest.approx(im.score(), rel=1e-4, abs=1e-6)
        assert got["dynamic_share"] == pytest.approx(share)
    masks = {
        n: np.stack([colour_labels(r, b) == 1 for r in rgbs])
        for n, b in (("low", 100.0), ("mid", 128.0))
    }
    pair = next(p for p in result["agreement"] if (p["a"], p["b"]) == ("low", "mid"))
    inter = (masks["low"] & masks["mid"]).sum()
    assert pair["mask_iou"] == pytest.approx(inter / (masks["low"] | masks["mid"]).sum())
    near = next(p for p in result["agreement"] if (p["a"], p["b"]) == ("mid", "near"))
    assert not near["separated"]
    assert "mid and near: masks not separated" in "\n".join(printed)
    assert printed[-1] == result["verdict"] and printed[-1].endswith(".")
    assert (out / "contact_sheet.png").is_file() and (out / "validators.png").is_file()
    assert "![contact sheet](contact_sheet.png)" in (out / "report.md").read_text()
    assert len(result["contact_frames"]) == 6


def test_compare_with_labels_intervals_and_few_frames_warning(
    tmp_path: Path, synthetic_sequence, models, capsys
) -> None:
    seq = synthetic_sequence(frames=8, size=(64, 48))
    out = tmp_path / "report"
    args = [str(models[0]), str(models[1]), "--sequence", str(seq), "--labels", str(seq / "labels"),
            "--label-frames", "4", "--out", str(out), "--validators", "entropy"]  # fmt: skip
    assert main(["compare", *args]) == 0
    captured = capsys.readouterr()
    assert (
        "--labels: 4 labelled frames (fewer than 15): the person-IoU differences have 95% intervals"
        in captured.err
    )
    result = json.loads((out / "compare.json").read_text())
    files = read_file_list(seq / "rgb.txt")
    picks = np.unique(np.linspace(0, 7, 4).round().astype(int))
    for name, bias in (("low", 100.0), ("mid", 128.0)):
        matrix = np.zeros((4, 4), np.int64)
        for k in picks:
            rgb = cv2.cvtColor(cv2.imread(str(files.resolve(k))), cv2.COLOR_BGR2RGB)
            truth = cv2.imread(str(seq / "labels" / files.resolve(k).name), cv2.IMREAD_UNCHANGED)
            pred = colour_labels(rgb, bias)
            valid = truth != 255
            np.add.at(matrix, (truth[valid], pred[valid]), 1)
        assert result["person_iou"][name]["value"] == pytest.approx(iou_from_matrix(matrix)[1])
        assert (
            result["person_iou"][name]["low"]
            <= result["person_iou"][name]["value"]
            <= result["person_iou"][name]["high"]
        )
    d = result["person_iou_difference"]["mid - low"]
    assert d["value"] == pytest.approx(
        result["person_iou"]["mid"]["value"] - result["person_iou"]["low"]["value"]
    )
    assert result["labelled_frames"] == 4
    last = captured.out.strip().splitlines()[-1]
    assert last.startswith(("Use ", "No model is better on 4 labelled frames"))


def _bad_sequence(tmp_path: Path, seq: Path, what: str) -> Path:
    bad = tmp_path / f"bad_{what}"
    shutil.copytree(seq, bad)
    files = read_file_list(bad / "rgb.txt")
    if what == "empty":
        (bad / "rgb.txt").write_text("# timestamp filename\n")
    elif what == "unreadable":
        files.resolve(2).write_bytes(b"not a png")
    elif what == "label_size":
        cv2.imwrite(str(bad / "labels" / files.resolve(0).name), np.zeros((5, 5), np.uint8))
    elif what == "label_ids":
        cv2.imwrite(str(bad / "labels" / files.resolve(0).name), np.full((48, 64), 9, np.uint8))
    return bad


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("one_model", "MODEL: expected two or more exported models, got 1"),
        ("twice", "low2.onnx: the same model as"),
        ("classes", "other.onnx: classes ['background', 'person', 'monitor', 'chair'] differ from"),
        ("empty", "rgb.txt: the sequence lists no images"),
        ("unreadable", ".png: not a readable image"),
        ("label_size", "labels are 5x5 but the colour image"),
        ("label_ids", "label values 9 are not class ids; expected 0..3"),
        ("label_count", "--label-frames 50: the --labels folders hold 6 label files"),
        ("unknown_validator", "--validators: unknown validator 'bogus'"),
        ("probe_no_source", "--validators probe: needs --source FOLDER"),
        ("static_unknown", "--static nope: not a compared sequence; expected one of walking_xyz_6"),
        ("static_no_slam", "--static needs --slam"),
        ("one_repeat", "--repeats: expected an integer >= 2"),
        ("no_repeat", "--repeats: expected an integer >= 2 (a range needs two runs), got '0'"),
    ],
)
def test_bad_inputs_one_line_before_any_work(
    tmp_path: Path, synthetic_sequence, models, capsys, case: str, message: str
) -> None:
    seq = synthetic_sequence(frames=6, size=(64, 48))
    out = tmp_path / "report"
    chosen = [str(models[0]), str(models[1])]
    extra: list[str] = []
    if case == "one_model":
        chosen = chosen[:1]
    elif case == "twice":
        copy = tmp_path / "copy" / "low2.onnx"
        copy.parent.mkdir()
        shutil.copy(models[0], copy)
        chosen = [str(models[0]), str(copy)]
    elif case == "classes":
        meta = segmenter_metadata(("background", "person", "monitor", "chair"))
        chosen = [chosen[0], str(raw_colour_model(tmp_path / "other.onnx", meta.to_props()))]
    elif case in ("empty", "unreadable"):
        seq = _bad_sequence(tmp_path, seq, case)
    elif case in ("label_size", "label_ids"):
        seq = _bad_sequence(tmp_path, seq, case)
        extra = ["--labels", str(seq / "labels")]
    elif case == "label_count":
        extra = ["--labels", str(seq / "labels"), "--label-frames", "50"]
    elif case == "unknown_validator":
        extra = ["--validators", "entropy,bogus"]
    elif case == "probe_no_source":
        extra = ["--validators", "probe"]
    elif case == "static_unknown":
        extra = ["--slam", "--static", "nope"]
    elif case == "static_no_slam":
        extra = ["--static", seq.name]
    elif case in ("one_repeat", "no_repeat"):
        extra = ["--slam", "--repeats", "1" if case == "one_repeat" else "0"]
    with pytest.raises(SystemExit) as stop:
        main(["compare", *chosen, "--sequence", str(seq), "--out", str(out), *extra])
    code = stop.value.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0
    if case.endswith("_repeat"):  # an option's range: argparse's usage, then the one line
        assert code == 2 and err[0].startswith("usage:")
        err = [line for line in err if line.startswith("uss-eval compare: error: ")]
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_probe_with_source_images(tmp_path: Path, synthetic_sequence, models, capsys) -> None:
    seq = synthetic_sequence(frames=10, size=(64, 48))
    src = synthetic_sequence(frames=10, size=(64, 48), style="source", seed=1)
    out = tmp_path / "report"
    code = main(["compare", str(models[0]), str(models[1]), "--sequence", str(seq), "--source",
                 str(src / "rgb"), "--validators", "probe", "--out", str(out)])  # fmt: skip
    assert code == 0
    result = json.loads((out / "compare.json").read_text())
    for name in ("low", "mid"):
        assert 0.0 <= result["validators"][name]["probe"] <= 1.0
    assert CLASS_NAMES[1] == "person"


@pytest.mark.slow
def test_slam_rows_one_rule_and_static_cost(
    tmp_path: Path, synthetic_sequence, models, capsys
) -> None:
    walking = synthetic_sequence(preset="walking_xyz", frames=30, size=(160, 120))
    static = synthetic_sequence(preset="static_xyz", frames=30, size=(160, 120))
    out = tmp_path / "report"
    code = main(["compare", str(models[0]), str(models[1]), "--sequence", str(walking),
                 "--sequence", str(static), "--slam", "--repeats", "2", "--static", static.name,
                 "--validators", "entropy", "--out", str(out)])  # fmt: skip
    assert code == 0
    result = json.loads((out / "compare.json").read_text())
    for seq in (walking.name, static.name):
        rows = result["slam"][seq]
        assert [r["row"] for r in rows] == ["no filter", "low", "mid"]
        for r in rows:
            assert r["min"] is None or r["min"] <= r["median"] <= r["max"]
    costs = [f for f in result["findings"] if f.startswith(f"{static.name} (static): ")]
    assert len(costs) == 2
    assert "## SLAM (ATE RMSE" in (out / "report.md").read_text()

"""``uss-demo --experiment ci``: the whole demo pipeline end to end on tiny data (slow): both
trainings from the packaged init, the AdaBN export, repeated SLAM runs and what the table says;
then a second call that reuses every stage."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.files import file_sha256
from uss_slam.core.onnx_contract import SegmenterMetadata
from uss_slam.pipelines import demo, demo_report
from uss_slam.pipelines.assets import demo_init_path
from uss_slam.pipelines.runs import select_checkpoint
from uss_slam.pipelines.stages import STAMP
from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

ROW_KEYS = {
    "variant", "label", "segmenter", "filters", "ate_rmse", "ate_min", "ate_max", "repeats",
    "tracked_fraction", "fps", "segmentation_ms", "mIoU", "person_IoU", "keypoints",
}  # fmt: skip
SEGMENTERS = {
    "none": "none",
    "labels": "labels",
    "source_only": "onnx:source_only.onnx",
    "adabn": "onnx:adabn.onnx",
    "adapted": "onnx:adapted.onnx",
    "adapted_geometry": "onnx:adapted.onnx",
}
STEPS = 14  # data, 2 trainings, 3 exports, mIoU, 6 SLAM rows, report


@pytest.mark.slow
def test_demo_ci_end_to_end_then_reused(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "demo"
    assert demo.main(["--out", str(out), "--experiment", "ci", "--quiet"]) == 0
    printed = capsys.readouterr().out

    # One table, printed and in the report, one row per variant in order.
    table = [line for line in printed.splitlines() if line.startswith("| ")]
    assert table[0] == demo_report.TABLE_HEADER
    assert [row.split(" | ")[0][2:] for row in table[1:]] == [v.label for v in demo.VARIANTS]
    report = (out / "report.md").read_text()
    assert "\n".join(table[:1]) in report and all(row in report for row in table[1:])
    summary = json.loads((out / "summary.json").read_text())
    # What the numbers say: printed under the table and in the report, computed from the rows.
    adapted = demo_report.training_metrics(out / "train" / "adapted")
    assert adapted is not None and "train/d_at_chance" in adapted
    assert summary["findings"] == demo_report.findings(summary["rows"], adapted)
    assert len(summary["findings"]) == 4
    assert all(line in printed and line in report for line in summary["findings"])
    assert summary["findings"][2].startswith("The adapted training's discriminators ")
    assert summary["findings"][3].startswith(
        ("Geometry helps: ", "Geometry lowers the median ATE: ", "Geometry does not help here: ")
    )
    for plot in ("ate_rmse.png", "trajectories.png"):
        assert (out / plot).stat().st_size > 1000 and f"]({plot})" in report

    assert summary["experiment"] == "ci" and summary["slam_repeats"] == 2
    assert summary["init"]["sha256"] == file_sha256(demo_init_path())
    assert summary["sequence"] == str(out / "data" / "slam" / "walking_xyz")
    assert set(summary["stage_seconds"]) == {"data", "train", "export", "miou", "slam"}
    rows = summary["rows"]
    assert [r["variant"] for r in rows] == [v.name for v in demo.VARIANTS]
    for row, variant in zip(rows, demo.VARIANTS, strict=True):
        assert set(row) == ROW_KEYS
        assert row["filters"] == list(variant.filters)
        assert row["segmenter"] == SEGMENTERS[variant.name]
        metrics = json.loads((out / "slam" / variant.name / "metrics.json").read_text())
        assert row["ate_rmse"] == metrics["ate"]["rmse"] and row["fps"] == metrics["fps"] > 0
        assert metrics["frames"] == 30 and metrics["filters"] == list(variant.filters)
        # slam.repeats=2: the folder is the median run's, the range spans both runs
        assert row["repeats"] == len(metrics["repeats"]) == 2
        spread = metrics["ate_rmse_repeats"]
        assert (row["ate_min"], row["ate_max"]) == (spread["min"], spread["max"])
        assert spread["min"] <= row["ate_rmse"] <= spread["max"]
        for name in ("trajectory.txt", "report.md", "trajectory.png", "ate.png", "map.ply"):
            assert (out / "slam" / variant.name / name).is_file(), (variant.name, name)
        assert f"](slam/{variant.name}/trajectory.png)" in report
    by_name = {r["variant"]: r for r in rows}
    assert by_name["labels"]["mIoU"] == 1.0 and by_name["none"]["mIoU"] is None
    assert by_name["none"]["segmentation_ms"] is None

    # mIoU of the exported models on the SLAM sequence: consistent per-class numbers.
    miou = json.loads((out / "miou.json").read_text())["scores"]
    assert set(miou) == {"adapted", "adabn", "source_only"}
    for name, scores in miou.items():
        assert scores["frames"] == 6  # 30 frames, every 5th
        present = [v for v in scores["IoU"].values() if v is not None]
        assert set(scores["IoU"]) == set(CLASS_NAMES)
        assert scores["mIoU"] == pytest.approx(float(np.mean(present)))
        assert by_name[name]["mIoU"] == scores["mIoU"]

    # Exports: verified, self-describing, tied to the training run's last checkpoint; AdaBN is
    # source-only's checkpoint with other BatchNorm statistics (other labels on target frames).
    for name, training in demo.MODELS.items():
        model = out / "exports" / f"{name}.onnx"
        verify = json.loads((out / "exports" / f"{name}.verify.json").read_text())
        assert verify["ok"] is True and verify["max_abs_logit_diff"] <= 1e-4
        seg = OnnxSegmenter(model)
        meta: SegmenterMetadata = seg.metadata
        assert meta.experiment == f"ci_{name}" and meta.class_names == CLASS_NAMES
        ckpt = select_checkpoint(out / "train" / training)
        assert (
            ckpt.name == "last.ckpt"  # the protocol's default: no target labels choose it
            and meta.checkpoint_sha256 == hashlib.sha256(ckpt.read_bytes()).hexdigest()
        )
        assert (out / "train" / training / ".hydra" / "config.yaml").is_file()
    assert (out / "exports" / "adabn.onnx").read_bytes() != (
        out / "exports" / "source_only.onnx"
    ).read_bytes()
    stamps = {
        name: json.loads((out / "train" / name / STAMP).read_text()) for name in demo.TRAININGS
    }
    assert "model/method=adaptsegnet" in stamps["adapted"]["overrides"]
    assert "model/method=source_only" in stamps["source_only"]["overrides"]
    for name, stamp in stamps.items():  # both from the packaged init, keyed on its content
        assert f"model.net.weights_path={demo_init_path()}" in stamp["overrides"], name
        assert stamp["init"] == file_sha256(demo_init_path())
    comparison = (out / "slam" / "comparison.md").read_text()
    assert all(f" {v.name} " in comparison.splitlines()[2] for v in demo.VARIANTS)

    # Second call: every stage is reused, the numbers are the same files.
    mtimes = {p: p.stat().st_mtime_ns for p in out.rglob("metrics.json")}
    assert demo.main(["--out", str(out), "--experiment", "ci", "--quiet"]) == 0
    again = capsys.readouterr().out
    done = [line for line in again.splitlines() if line.startswith("[") and " in " in line]
    assert len(done) == STEPS
    assert all(": reused in " in line for line in done[:-1]), done
    assert {p: p.stat().st_mtime_ns for p in out.rglob("metrics.json")} == mtimes
    assert json.loads((out / "summary.json").read_text())["rows"] == rows

    # --sequence DIR: the folder's content keys the stages that read it. Frames rewritten
    # under the same names redo the mIoU and SLAM stages, saying why; the rest is reused.
    seq = tmp_path / "seq"
    shutil.copytree(out / "data" / "slam" / "walking_xyz", seq)
    argv = ["--out", str(out), "--experiment", "ci", "--quiet", "--sequence", str(seq)]
    assert demo.main(argv) == 0
    capsys.readouterr()
    for frame in sorted((seq / "rgb").iterdir())[:10]:
        cv2.imwrite(str(frame), 255 - cv2.imread(str(frame)))
        later = frame.stat().st_mtime_ns + 10**9  # a new time even on a coarse clock
        os.utime(frame, ns=(later, later))
    assert demo.main(argv) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("[")]
    done = [line for line in lines if " in " in line and " ..." not in line]
    assert all(": reused in " in line for line in done[:6]), done  # data, trainings, exports
    assert ": redone (sequence changed): " in done[6], done[6]  # mIoU
    assert all(": redone (inputs.sequence changed): " in line for line in done[7:13]), done
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sequence"] == str(seq)
    assert [r["ate_rmse"] for r in summary["rows"]] != [r["ate_rmse"] for r in rows]

    # A changed uss-slam default (as a release that changes the tracker policy) redoes the
    # SLAM stages, which were keyed on their overrides only before, and nothing else.
    monkeypatch.setattr(demo, "slam_defaults_key", lambda: "other defaults")
    assert demo.main(argv) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("[")]
    done = [line for line in lines if " in " in line and " ..." not in line]
    assert all(": reused in " in line for line in done[:7]), done  # up to mIoU
    assert all(": redone (defaults changed): " in line for line in done[7:13]), done


def test_options_default_to_reuse() -> None:
    parser = demo.build_parser()
    assert parser.parse_args([]).force is False
    assert parser.parse_args(["--reuse"]).force is False
    assert parser.parse_args(["--force"]).force is True
    args = parser.parse_args([])
    assert (args.out, args.experiment, args.sequence) == (
        Path("outputs/demo"),
        "demo",
        "walking_xyz",
    )


def test_unknown_sequence_is_a_one_line_error(tmp_path: Path, capsys) -> None:
    """A bad --sequence fails before any work, naming the choices."""
    with pytest.raises(SystemExit) as exit_info:
        demo.main(["--out", str(tmp_path), "--experiment", "ci", "--quiet",
                   "--sequence", "nowhere"])  # fmt: skip
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        "uss-demo: error: --sequence=nowhere: does not exist"
    )
    assert "walking_xyz, static_xyz" in err[0] and not (tmp_path / "data").exists()

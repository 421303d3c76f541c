"""studies/adaptation_masks.py's experiment mode: every export of a uss-experiments folder
scored on the labelled evaluation sequences, joined with its SLAM runs, and the rank
correlation of each SLAM ratio with each mask figure."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest
from shared_helpers import colour_segmenter as colour_model

from uss_slam.pipelines.experiments.tables import COLUMNS
from uss_slam.testing.downstream import slam_ratios
from uss_slam.testing.scripts import load_script

adaptation_masks = load_script(
    Path(__file__).resolve().parents[2] / "studies" / "adaptation_masks.py"
)
experiment, join, joined_table, main = (
    adaptation_masks.experiment,
    adaptation_masks.join,
    adaptation_masks.joined_table,
    adaptation_masks.main,
)


def _slam(sequence: str, variant: str, ate: float, model: str = "", system: str = "harness",
          status: str = "ok") -> dict:  # fmt: skip
    base = f"slam/{system}/{sequence}/{variant}"
    return {"kind": "slam", "id": f"{base}/{model}" if model else base, "status": status,
            "system": system, "sequence": sequence, "variant": variant, "ate_rmse": ate,
            "config": model.rsplit("_s", 1)[0] if model else ""}  # fmt: skip


def test_slam_ratios_downstream_on_walkers_and_ate_ratio_on_static() -> None:
    runs = [
        _slam("walking_xyz", "none", 0.40),
        _slam("walking_xyz", "oracle", 0.00),
        _slam("walking_xyz", "semantic", 0.10, "m_s0"),
        _slam("walking_xyz", "semantic", 0.30, "m_s0", status="failed"),  # not used
        _slam("walking_xyz", "semantic", 0.35, "other_s0"),
        _slam("static_xyz", "none", 0.004),
        _slam("static_xyz", "semantic", 0.005, "m_s0"),
    ]
    walking = slam_ratios(runs, "walking_xyz", "m_s0")
    assert walking["harness:semantic"] == pytest.approx(0.75)
    assert walking["harness:semantic_geometry"] is None  # no such run
    assert walking["orbslam3:semantic"] is None
    assert slam_ratios(runs, "static_xyz", "m_s0")["harness:semantic"] == pytest.approx(1.25)
    # the ground-truth masks gaining nothing: no ratio
    flat = [*runs[:1], _slam("walking_xyz", "oracle", 0.40), runs[2]]
    assert slam_ratios(flat, "walking_xyz", "m_s0")["harness:semantic"] is None


def _mask(recall: float, kept: float) -> dict:
    return {"sequences": {"walking_xyz": {"argmax": {
        "person_iou": 0.5, "pixels": {"recall": recall, "precision": 0.7},
        "kp_person_kept": kept, "kp_static_dropped": 0.1, "dyn_share": kept / 4}}}}  # fmt: skip


def test_join_correlates_over_the_trained_models_only() -> None:
    runs = [_slam("walking_xyz", "none", 1.0), _slam("walking_xyz", "oracle", 0.0)]
    masks = {}
    for k, (recall, ate) in enumerate([(0.5, 0.6), (0.6, 0.5), (0.7, 0.3), (0.8, 0.2)]):
        masks[f"m_s{k}"] = _mask(recall, 1 - recall)
        runs.append(_slam("walking_xyz", "semantic", ate, f"m_s{k}"))
    masks["oracle_s0"] = _mask(0.1, 0.9)  # would break the ranking if it were counted
    runs.append(_slam("walking_xyz", "semantic", 0.0, "oracle_s0"))
    joined = join(masks, runs, ["walking_xyz"])
    part = joined["walking_xyz"]
    assert len(part["models"]) == 5
    corr = part["spearman"]["harness:semantic"]
    assert corr["models"] == 4
    assert corr["rho"]["recall"] == pytest.approx(1.0)
    assert corr["rho"]["kp_person_kept"] == pytest.approx(-1.0)
    assert corr["rho"]["person_iou"] is None  # constant: no correlation
    assert "harness:semantic_geometry" not in part["spearman"]
    table = joined_table(joined)
    assert "| m_s2 | 0.500 | 0.700 | 0.700 | 30.0% |" in table
    assert "pixel recall +1.00" in table


def _experiment(tmp_path: Path, sequence: Path) -> Path:
    out = tmp_path / "exp"
    shutil.copytree(sequence, out / "data" / "eval" / "walking_xyz")
    for model in ("source_only_s0", "adaptsegnet_n5_s0"):
        (out / "exports" / model).mkdir(parents=True)
        colour_model(out / "exports" / model / f"{model}.onnx", bias=128.0 if "source" in model
                     else 90.0)  # fmt: skip
    rows = [
        _slam("walking_xyz", "none", 0.30),
        _slam("walking_xyz", "oracle", 0.01),
        _slam("walking_xyz", "semantic", 0.20, "source_only_s0"),
        _slam("walking_xyz", "semantic", 0.10, "adaptsegnet_n5_s0"),
    ]
    with (out / "runs.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: r.get(k, "") for k in COLUMNS})
    return out


def test_experiment_mode_scores_every_export_and_keeps_the_result(
    tmp_path: Path, synthetic_sequence, capsys
) -> None:
    out = _experiment(tmp_path, synthetic_sequence(frames=10))
    assert (
        main(["--experiment", str(out), "--stride", "5", "--json", str(tmp_path / "j.json")]) == 0
    )
    printed = capsys.readouterr().out
    assert "## walking_xyz (SLAM columns: downstream ratio)" in printed
    assert "| adaptsegnet_n5_s0 |" in printed and "| source_only_s0 |" in printed
    cached = out / "masks" / "source_only_s0.json"
    assert cached.is_file() and (tmp_path / "j.json").is_file()
    before = cached.stat().st_mtime_ns
    joined = experiment(out, ["walking_xyz"], ["source_only_s0"], 5, 5)
    assert cached.stat().st_mtime_ns == before  # reused, not scored again
    row = joined["walking_xyz"]["models"][0]
    assert row["harness:semantic"] == pytest.approx((0.30 - 0.20) / (0.30 - 0.01))
    # another stride is another result: scored again
    experiment(out, ["walking_xyz"], ["source_only_s0"], 2, 5)
    assert cached.stat().st_mtime_ns != before


def test_experiment_mode_bad_input_names_what_was_expected(
    tmp_path: Path, synthetic_sequence
) -> None:
    with pytest.raises(SystemExit, match="runs.csv: no runs.csv"):
        experiment(tmp_path, None, None, 5, 5)
    out = _experiment(tmp_path, synthetic_sequence(frames=10))
    with pytest.raises(
        SystemExit,
        match="--models: mystery_s0 has no export .*found: adaptsegnet_n5_s0, source_only_s0",
    ):
        experiment(out, None, ["mystery_s0"], 5, 5)
    with pytest.raises(
        SystemExit,
        match="--sequences: static_xyz is not a labelled evaluation sequence .*found: walking_xyz",
    ):
        experiment(out, ["static_xyz"], None, 5, 5)
    with pytest.raises(SystemExit):
        main(["--experiment", str(out), "model.onnx"])

"""studies/warm_start_hypotheses.py on a fake output folder: segmentation pooled over the
walking sequences only (the static control apart), paired differences by seed, the
protocol's decision rules, and the downstream ratio from runs.csv."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from uss_slam.testing.scripts import load_script

study = load_script(Path(__file__).resolve().parents[2] / "studies" / "warm_start_hypotheses.py")
SEQUENCES = (*study.WALKING, study.CONTROL)


def _person_matrix(person_iou: float) -> list[list[int]]:
    """A 4-class confusion matrix whose person IoU is ``person_iou`` (others: 1)."""
    hit = round(1000 * person_iou)
    matrix = np.diag([1000, hit, 1000, 1000])
    matrix[1, 0] = 1000 - hit  # missed person pixels
    return matrix.tolist()


def _write(out: Path, model: str, seed: int, walking: float, static: float) -> None:
    folder = out / "segeval" / f"{model}_s{seed}"
    folder.mkdir(parents=True)
    sequences = {s: {"confusion": _person_matrix(walking)} for s in study.WALKING}
    sequences[study.CONTROL] = {"confusion": _person_matrix(static)}
    (folder / "result.json").write_text(json.dumps({"sequences": sequences}))


def test_pools_walking_only_and_applies_the_decision_rules(tmp_path: Path) -> None:
    gains = {0: 0.20, 1: 0.22, 2: 0.18}
    for seed, gain in gains.items():
        _write(tmp_path, "source_only", seed, 0.5, 0.9)
        _write(tmp_path, "adabn", seed, 0.5 + gain, 0.1)  # the control must not leak in
        _write(tmp_path, study.ADAPTSEGNET, seed, 0.5 + gain, 0.9)
    walking = study.seg_scores(tmp_path, study.WALKING)
    assert walking["adabn"][1]["person"] == 100 * (0.5 + 0.22)
    h1 = study.paired(walking, "adabn", "source_only", "person")
    assert np.allclose(h1["values"], [100 * g for g in gains.values()])
    assert study.one_sided(h1) == "holds (interval above 0)"
    h3 = study.paired(walking, study.ADAPTSEGNET, "adabn", "person")
    assert np.allclose(h3["values"], 0)  # equal on every seed: s = 0, MDE 0
    assert study.two_sided(h3).startswith("decided: equivalent")
    control = study.seg_scores(tmp_path, (study.CONTROL,))
    assert study.one_sided(study.paired(control, "source_only", "adabn", "person")).startswith(
        "holds"
    )


def test_downstream_ratio_from_runs_csv(tmp_path: Path) -> None:
    rows = [("slam/harness/walking_xyz/none", 0.10), ("slam/harness/walking_xyz/oracle", 0.02)]
    for seed in range(3):
        rows += [
            (f"slam/harness/walking_xyz/semantic/source_only_s{seed}", 0.08),
            (f"slam/harness/walking_xyz/semantic/adabn_s{seed}", 0.04 + 0.001 * seed),
        ]
    with (tmp_path / "runs.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, ["kind", "id", "status", "ate_rmse"])
        writer.writeheader()
        writer.writerows({"kind": "slam", "id": i, "status": "ok", "ate_rmse": a} for i, a in rows)
    found = study.slam_ratios(tmp_path)[("harness", "walking_xyz")]
    ratio, relative = found["adabn"][0]
    assert np.isclose(ratio, (0.10 - 0.04) / (0.10 - 0.02)) and np.isclose(relative, 0.4)
    assert np.isclose(found["source_only"][2][0], 0.25)


def test_a_result_without_confusion_matrices_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "segeval" / "source_only_s0"
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps({"sequences": {"walking_xyz": {}}}))
    with pytest.raises(SystemExit, match=r"result\.json: no confusion matrix for walking_xyz"):
        study.seg_scores(tmp_path, study.WALKING)


def test_seeds_keeps_a_subset_and_refuses_absent_seeds(tmp_path: Path, capsys) -> None:
    for seed in range(4):
        _write(tmp_path, "source_only", seed, 0.5, 0.9)
        _write(tmp_path, "adabn", seed, 0.5 + 0.1 * seed, 0.9)
    assert study.parse_seeds("0-2,5") == {0, 1, 2, 5}
    for bad in ("a", "3-1", "1-2-3", ""):
        with pytest.raises(Exception, match="expected seeds|must go up"):
            study.parse_seeds(bad)
    walking = study.keep_seeds(study.seg_scores(tmp_path, study.WALKING), {0, 1})
    assert study.paired(walking, "adabn", "source_only", "person")["values"] == pytest.approx(
        [0.0, 10.0]
    )
    (tmp_path / "runs.csv").write_text("kind,id,status,ate_rmse\n")
    assert study.main([str(tmp_path), "--seeds", "0-1"]) == 0
    assert "| source_only | 2 |" in capsys.readouterr().out
    with pytest.raises(SystemExit, match=r"no model has seed\(s\) 4, 5; the folder has 0, 1, 2, 3"):
        study.main([str(tmp_path), "--seeds", "3-5"])

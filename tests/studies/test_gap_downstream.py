"""studies/gap_downstream.py on fake files: the keypoint mediator's counts, the SLAM runs'
collection, the downstream ratio, the paired figures with the reading rule, the static
control, and the bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import write_csv

from uss_slam.testing.scripts import load_script

ROOT = Path(__file__).resolve().parents[2] / "studies"
down = load_script(ROOT / "gap_downstream.py")


def test_keypoints_on_walkers_and_on_static_structure_and_what_a_mask_removes() -> None:
    truth = np.zeros((40, 40), np.uint8)
    truth[10:20, 10:20] = down.PERSON
    pred = np.zeros((40, 40), bool)
    pred[10:20, 10:15] = True  # half the walker, nothing else
    xy = np.array([[12, 12], [18, 12], [30, 30], [35, 5], [13.4, 18.6]], float)
    counts = down.keypoint_counts(truth, pred, xy, down._kernel(1))
    assert counts == {"walker_kp": 3, "walker_removed": 2, "static_kp": 2, "static_removed": 0}
    # The dilation reaches a static keypoint one pixel outside the predicted mask.
    near = np.array([[15, 20]], float)
    truth2 = np.zeros((40, 40), np.uint8)
    pred2 = np.zeros((40, 40), bool)
    pred2[10:25, 10:15] = True
    assert down.keypoint_counts(truth2, pred2, near, down._kernel(1))["static_removed"] == 1


def _metrics(folder: Path, ate: float | None) -> None:
    folder.mkdir(parents=True)
    reps = None if ate is None else {"median": ate, "min": ate * 0.9, "max": ate * 1.1}
    body = {"ate": None if ate is None else {"rmse": ate}, "ate_rmse_repeats": reps,
            "tracked_fraction": 1.0 if ate is not None else 0.0}  # fmt: skip
    (folder / "metrics.json").write_text(json.dumps(body))


def _runs(root: Path, gains: dict[str, list[float]]) -> None:
    """Harness runs on four renders: none 0.10 m, oracle 0.02 m, each row's seeds at the
    ratio given (render r adds 0.01 * r to every ratio)."""
    for r in range(4):
        render = root / "harness" / f"walking_xyz_{8300 + 100 * r}"
        _metrics(render / "none", 0.10)
        _metrics(render / "oracle", 0.02)
        for row, ratios in gains.items():
            for seed, ratio in enumerate(ratios):
                ate = 0.10 - (ratio + 0.01 * r) * 0.08
                _metrics(render / f"{row}_s{seed}", ate)


def test_collect_then_ratios_and_the_reading_rule(tmp_path: Path) -> None:
    _runs(
        tmp_path / "runs",
        {"adabn_bntrained": [0.5, 0.6, 0.7], "source_only_bntrained": [0.3, 0.4, 0.2]},
    )
    rows = down.collect(tmp_path / "runs")
    assert len(rows) == 4 * 8 and {r["system"] for r in rows} == {"harness"}
    one = next(r for r in rows if r["run"] == "adabn_bntrained_s1" and r["render_seed"] == 8300)
    assert one["row"] == "adabn_bntrained" and one["seed"] == "1"
    assert one["ate_median"] == pytest.approx(0.10 - 0.6 * 0.08)
    ratios = down.slam_ratios(rows, "harness")
    assert ratios[("walking_xyz_8300", "adabn_bntrained")] == pytest.approx([0.5, 0.6, 0.7])
    diffs = down.per_render(ratios, "adabn_bntrained", "source_only_bntrained")
    assert diffs == pytest.approx([0.3] * 4)  # the render term cancels in the pairing


def test_paired_figures_and_the_three_readings() -> None:
    shown = down.paired([0.2, 0.3, 0.25, 0.22, 0.28])
    assert shown["lo"] > 0 and down.reading(shown) == "shown"
    assert shown["n"] == 5 and shown["above_0"] == 5 and shown["mde"] > 0
    refuted = down.paired([0.01, -0.01, 0.0, 0.005, -0.004, 0.002])
    assert down.reading(refuted).startswith("refuted")
    wide = down.paired([0.5, -0.4, 0.3, -0.2])
    assert down.reading(wide) == "not shown"
    assert down.reading(down.paired([-0.2, -0.3, -0.25])) == "shown (negative)"


def test_figures_recompute_from_the_committed_files(tmp_path: Path) -> None:
    _runs(tmp_path / "runs", {"adabn_bntrained": [0.5, 0.6], "source_only_bntrained": [0.5, 0.6]})
    static = tmp_path / "runs" / "harness" / "static_xyz_9200"
    _metrics(static / "none", 0.010)
    _metrics(static / "adabn_bntrained_s0", 0.012)
    _metrics(static / "source_only_bntrained_s0", 0.010)
    slam = write_csv(tmp_path / "slam.csv", down.collect(tmp_path / "runs"))
    med = []
    for r in range(4):
        for row, removed in (("adabn_bntrained", 60 + r), ("source_only_bntrained", 40)):
            med.append({"model": f"{row}_s0", "row": row, "seed": "0", "preset": "walking_xyz",
                        "block": 8300 + 100 * r, "render_seed": 8300 + 100 * r,
                        "walker_kp": 100, "walker_removed": removed, "static_kp": 200,
                        "static_removed": 4})  # fmt: skip
    mediator = write_csv(tmp_path / "med.csv", med)
    text = down.figures(down.read_csv(mediator), down.read_csv(slam), "adabn_bntrained",
                        "source_only_bntrained")  # fmt: skip
    assert "| mediator: walker_removed | +0.215 [" in text and "| shown |" in text
    assert "| harness: downstream ratio | +0.000 [+0.000, +0.000]" in text
    assert "Spearman" not in text  # the ratio difference is constant: no rank correlation
    walker = {f"r{i}": float(i) for i in range(5)}
    assert down.link(walker, {f"r{i}": float(i * i) for i in range(5)}).startswith("Spearman +1.00")
    assert (
        "static_xyz_9200 (nothing moves; no filter 0.0100 m), adabn_bntrained: ATE / no filter x1.20"
        in text
    )


def test_bad_inputs_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="no finished run"):
        down.collect(tmp_path)
    with pytest.raises(SystemExit, match="no such file"):
        down.read_csv(tmp_path / "missing.csv")
    with pytest.raises(SystemExit, match="--vocabulary: required"):
        down.slam_command("orbslam3", tmp_path, "none", None, tmp_path / "o", None)
    with pytest.raises(SystemExit, match="no render"):
        down.main(["run", str(tmp_path), "--renders", str(tmp_path), "--blocks", "8300",
                   "--models", "a_s0", "--runs", str(tmp_path / "r"), "--system", "harness"])  # fmt: skip

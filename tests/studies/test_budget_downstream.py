"""studies/budget_downstream.py: finished jobs are read (median over repeats), not re-run, and
a missing input is one error naming it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from uss_slam.testing.scripts import load_script

budget_downstream = load_script(
    Path(__file__).resolve().parents[2] / "studies" / "budget_downstream.py"
)
(
    baseline_folder,
    baseline_text,
    downstream_ratio,
    export,
    filter_comparisons,
    main,
    paired_difference,
    paired_text,
    plot_ratios,
    pooled,
    pooled_lines,
    segeval,
    slam,
    slam_repeats,
) = (
    budget_downstream.baseline_folder,
    budget_downstream.baseline_text,
    budget_downstream.downstream_ratio,
    budget_downstream.export,
    budget_downstream.filter_comparisons,
    budget_downstream.main,
    budget_downstream.paired_difference,
    budget_downstream.paired_text,
    budget_downstream.plot_ratios,
    budget_downstream.pooled,
    budget_downstream.pooled_lines,
    budget_downstream.segeval,
    budget_downstream.slam,
    budget_downstream.slam_repeats,
)


def test_a_finished_job_is_read_not_run(tmp_path: Path) -> None:
    job = tmp_path / "job"
    job.mkdir()
    (job / "metrics.json").write_text(
        json.dumps({"ate": {"rmse": 0.5}, "ate_rmse_repeats": {"median": 0.25}})
    )
    # Overrides that uss-slam would reject: reading must not start it.
    assert slam(job, ["no.such.key=1"]) == 0.25
    (job / "metrics.json").write_text(json.dumps({"ate": {"rmse": 0.5}}))
    assert slam(job, ["no.such.key=1"]) == 0.5


def test_baselines_give_their_repeats_range_and_keep_a_folder_per_count(tmp_path: Path) -> None:
    job = tmp_path / "none_r21"
    job.mkdir()
    (job / "metrics.json").write_text(
        json.dumps({"ate": {"rmse": 0.5},
                    "ate_rmse_repeats": {"median": 0.0037, "min": 0.0033, "max": 0.0047}})
    )  # fmt: skip
    assert slam_repeats(job, ["no.such.key=1"]) == (0.0037, 0.0033, 0.0047)
    # the jobs with 3 repeats keep their folders: earlier outputs are still reused
    assert baseline_folder("none", 3) == "none" and baseline_folder("oracle", 21) == "oracle_r21"
    base = {"none": 0.0037, "oracle": 0.0036, "none_range": (0.0033, 0.0047)}
    assert baseline_text(base) == "3.7 (3.3–4.7) / 3.6"


def test_a_bad_baseline_repeat_count_is_one_error(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        main(["--experiment", str(tmp_path), "--runs", str(tmp_path), "--baseline-repeats", "0"])
    assert "--baseline-repeats: a count >= 1, got 0" in capsys.readouterr().err


def test_a_failed_job_names_its_folder(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="job.*uss-slam failed"):
        slam(tmp_path / "job", [f"sequence.path={tmp_path / 'missing'}"])


def test_missing_inputs_are_one_error_each(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        main(["--experiment", str(tmp_path), "--runs", str(tmp_path / "runs")])
    assert "vocabulary.txt is missing" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--experiment", str(tmp_path), "--runs", str(tmp_path), "--variants", "harness:crf"])
    err = capsys.readouterr().err
    assert "--variants: unknown harness:crf; choose from harness:semantic," in err
    with pytest.raises(SystemExit, match="source_only_s3.*no such checkpoint"):
        export(tmp_path, "source_only", 3, [])


def test_static_sequences_report_the_cost_of_filtering() -> None:
    base = {"none": 0.004, "oracle": 0.0041}
    assert downstream_ratio("static_xyz", base, 0.0044) == pytest.approx(1.1)
    walking = {"none": 0.2, "oracle": 0.005}
    assert downstream_ratio("walking_xyz", walking, 0.005) == pytest.approx(1.0)
    assert downstream_ratio("walking_xyz", walking, 0.2) == pytest.approx(0.0)


def test_rows_are_compared_paired_by_seed_with_an_interval() -> None:
    per = {
        "source_only": {0: {"ratio": 0.7}, 1: {"ratio": 0.6}, 2: {"ratio": 0.8}},
        "model": {0: {"ratio": 0.9}, 1: {"ratio": 0.9}, 2: {"ratio": 0.9}},
    }
    paired = paired_difference(per, "model", "source_only", [0, 1, 2])
    assert paired["values"] == pytest.approx([0.2, 0.3, 0.1])
    assert paired["positive"] == 3 and paired["mean"] == pytest.approx(0.2)
    # t(0.975, 2) = 4.303, s = 0.1: half-width 4.303 * 0.1 / sqrt(3) = 0.248
    lo, hi = paired["interval"]
    assert lo == pytest.approx(0.2 - 0.2484, abs=1e-3) and hi == pytest.approx(0.4484, abs=1e-3)
    assert paired_text(paired) == "+0.20 / +0.30 / +0.10 (3/3 > 0), mean +0.20 [-0.05, +0.45]"
    # a segmentation metric of the same layout, paired the same way
    seg = {"source_only": {0: {"person": 0.4}, 1: {"person": 0.5}},
           "model": {0: {"person": 0.6}, 1: {"person": 0.4}}}  # fmt: skip
    by_metric = paired_difference(seg, "model", "source_only", [0, 1], "person")
    assert by_metric["values"] == pytest.approx([0.2, -0.1]) and by_metric["positive"] == 1
    one = paired_difference(per, "model", "source_only", [0])
    assert one["interval"] is None and paired_text(one) == "+0.20 (1/1 > 0)"


def test_the_ratios_are_drawn_per_seed(tmp_path: Path) -> None:
    def cell(values: dict[str, list[float]]) -> dict:
        return {row: {s: {"ratio": r} for s, r in enumerate(rs)} for row, rs in values.items()}

    ate = {
        "harness/walking_xyz": {
            "baselines": {"none": 0.2, "oracle": 0.005},
            "semantic_geometry": cell({"source_only": [0.6, 0.7], "model": [0.9, 0.95]}),
        },
        "orbslam3/static_xyz": {
            "baselines": {"none": 0.004, "oracle": 0.004},
            "semantic": cell({"source_only": [1.02, 1.2], "model": [1.0, 1.05]}),
        },
    }
    out = plot_ratios(ate, ["source_only", "model"], [0, 1], tmp_path / "plots" / "d.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(out.parent.glob(".*.tmp.png"))
    with pytest.raises(ValueError, match="no downstream ratios"):
        plot_ratios({"harness/walking_xyz": {"baselines": {}}}, ["model"], [0], out)


def test_renders_of_one_preset_are_pooled_paired_by_seed() -> None:
    # two renders, two seeds: per seed the mean over the renders of row − base
    per_sequence = {
        "walking_rpy": {"source_only": {0: 0.6, 1: 0.2}, "model": {0: 0.9, 1: 0.2}},
        "walking_rpy_2002": {"source_only": {0: 0.4, 1: 0.6}, "model": {0: 0.5, 1: 0.9}},
    }
    pool = pooled(per_sequence, ["source_only", "model"], "source_only", [0, 1])
    assert pool["source_only"] == {"median": pytest.approx(0.5), "n": 4}
    assert pool["model"]["median"] == pytest.approx(0.7)
    paired = pool["model"]["paired"]
    assert paired["values"] == pytest.approx([0.2, 0.15]) and paired["positive"] == 2
    assert paired["mean"] == pytest.approx(0.175)
    lines = pooled_lines("harness, semantic_geometry", pool, "source_only")
    assert lines[2] == "| source_only | 0.500 (n = 4) | — |"
    assert lines[3].startswith("| model | 0.700 (n = 4) | +0.20 / +0.15 (2/2 > 0), mean +0.18 [")


def test_a_finished_segmentation_is_read_not_run(tmp_path: Path) -> None:
    job = tmp_path / "eval"
    job.mkdir()
    (job / "eval.json").write_text(json.dumps({"mIoU": 0.4, "IoU": {"person": 0.6, "chair": 0.1}}))
    # a model and a sequence that do not exist: reading must not start uss-eval
    assert segeval(job, tmp_path / "no.onnx", tmp_path / "none", 5) == {"mIoU": 0.4, "person": 0.6}
    with pytest.raises(SystemExit, match="other.*uss-eval failed"):
        segeval(tmp_path / "other", tmp_path / "no.onnx", tmp_path / "none", 5)


def test_a_bad_segeval_stride_is_one_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        main(["--experiment", str(tmp_path), "--runs", str(tmp_path), "--segeval", "0"])
    assert "--segeval: a frame stride >= 1, got 0" in capsys.readouterr().err


def test_models_outside_the_rows_or_without_the_base_are_one_error(tmp_path: Path, capsys):
    (tmp_path / "data" / "orbslam3_vocabulary").mkdir(parents=True)
    (tmp_path / "data" / "orbslam3_vocabulary" / "vocabulary.txt").write_text("")
    (tmp_path / "data" / "eval" / "walking_xyz").mkdir(parents=True)
    (tmp_path / "data" / "train" / "target_train").mkdir(parents=True)
    common = ["--experiment", str(tmp_path), "--runs", str(tmp_path), "--sequences", "walking_xyz"]
    with pytest.raises(SystemExit):
        main([*common, "--models", "source_only,advent+adabn"])
    err = capsys.readouterr().err
    assert "--models: unknown advent+adabn; the rows give source_only,source_only+adabn," in err
    with pytest.raises(SystemExit):
        main([*common, "--models", "source_only+adabn"])
    assert "--models: must include --base source_only" in capsys.readouterr().err


def test_two_filters_of_one_system_are_compared_model_by_model() -> None:
    def cell(grey: float, step: float) -> dict:
        return {
            "semantic": {"m": {0: {"ratio": grey}, 1: {"ratio": grey + 0.1}}},
            "semantic_inpaint": {"m": {0: {"ratio": grey + step}, 1: {"ratio": grey + 0.1}}},
        }

    ate = {"orbslam3/a": cell(0.2, 0.4), "orbslam3/b": cell(0.4, 0.2), "harness/a": {}}
    out = filter_comparisons(ate, ["a", "b"], ["m"], [0, 1])
    assert list(out) == ["orbslam3"]  # the harness ran one filter: nothing to compare
    ran, by_row = out["orbslam3"]
    assert ran == ["semantic", "semantic_inpaint"]
    pool = by_row["m"]
    assert pool["semantic"]["median"] == pytest.approx(0.35) and pool["semantic"]["n"] == 4
    # seed 0: inpaint − grey is +0.4 and +0.2 on the two sequences (mean +0.3); seed 1: 0
    assert pool["semantic_inpaint"]["paired"]["values"] == pytest.approx([0.3, 0.0])
    # a filter missing on one walking sequence is not compared
    del ate["orbslam3/b"]["semantic_inpaint"]
    assert filter_comparisons(ate, ["a", "b"], ["m"], [0, 1]) == {}

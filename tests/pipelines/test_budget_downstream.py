"""benchmarks/budget_downstream.py: finished jobs are read (median over repeats), not re-run, and
a missing input is one error naming it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from budget_downstream import downstream_ratio, export, main, slam


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


def test_a_failed_job_names_its_folder(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="job.*uss-slam failed"):
        slam(tmp_path / "job", [f"sequence.path={tmp_path / 'missing'}"])


def test_missing_inputs_are_one_error_each(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        main(["--experiment", str(tmp_path), "--runs", str(tmp_path / "runs")])
    assert "vocabulary.txt is missing" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="source_only_s3.*no such checkpoint"):
        export(tmp_path, "source_only", 3, [])


def test_static_sequences_report_the_cost_of_filtering() -> None:
    base = {"none": 0.004, "oracle": 0.0041}
    assert downstream_ratio("static_xyz", base, 0.0044) == pytest.approx(1.1)
    walking = {"none": 0.2, "oracle": 0.005}
    assert downstream_ratio("walking_xyz", walking, 0.005) == pytest.approx(1.0)
    assert downstream_ratio("walking_xyz", walking, 0.2) == pytest.approx(0.0)

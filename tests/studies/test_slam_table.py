"""studies/slam_table.py: one table of every stretch × stride × system, whose figures are
those of the run folders it keeps, with one clear error line for each bad input."""

from __future__ import annotations

import importlib.util
import json
import os
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "studies" / "slam_table.py"
_spec = importlib.util.spec_from_file_location("slam_table", SCRIPT)
slam_table = sys.modules.setdefault("slam_table", importlib.util.module_from_spec(_spec))
_spec.loader.exec_module(slam_table)
main = slam_table.main

REAL_DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "tum"
"""``../shared/data/tum`` next to the repository: the real TUM stretches, where present."""


def _error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert main(argv) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("slam_table: error: ")
    return lines[0]


def _tum_folder(path: Path, frames: int = 0) -> Path:
    """A TUM folder's lists without images: enough for the checks that come before a run."""
    path.mkdir(parents=True)
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        (path / name).write_text("# timestamp filename\n")
    return path


def test_bad_inputs_are_one_line_each(tmp_path: Path, capsys) -> None:
    out = ["--out", str(tmp_path / "out")]
    missing = tmp_path / "no_such_data"
    line = _error(capsys, ["--data", str(missing), "--no-synthetic", *out])
    assert f"--data {missing}: no such folder" in line
    (tmp_path / "empty").mkdir()
    line = _error(capsys, ["--data", str(tmp_path / "empty"), "--no-synthetic", *out])
    assert "no TUM sequence folder" in line
    for strides in ("0", "1,x", ""):
        line = _error(capsys, ["--strides", strides, "--data", str(missing), *out])
        assert f"--strides: expected comma-separated integers >= 1, got {strides!r}" in line
    line = _error(capsys, ["--systems", "harness,orbslam2", *out])
    assert "--systems: expected a comma-separated subset of" in line
    line = _error(capsys, ["--repeats", "0", *out])
    assert "--repeats: expected an integer >= 1, got 0" in line
    line = _error(capsys, ["--synthetic-timings", "kinect", "--no-real", *out])
    assert "--synthetic-timings" in line
    line = _error(capsys, ["--synthetic-presets", "walking_xyz", "--no-real", *out])
    assert "--synthetic-presets: expected a comma-separated subset of handheld_rpy," in line
    line = _error(capsys, ["--override", "tracker.readout=0", "--no-real", *out])
    assert "--override: expected slam.KEY=VALUE, got 'tracker.readout=0'" in line
    assert not (tmp_path / "out" / "table.md").exists()


def test_orbslam3_needs_a_vocabulary_from_another_stretch(tmp_path: Path, capsys) -> None:
    data = tmp_path / "data"
    _tum_folder(data / "stretch_a")
    argv = ["--data", str(data), "--no-synthetic", "--systems", "orbslam3"]
    line = _error(capsys, [*argv, "--out", str(tmp_path / "out")])
    assert "orbslam3 on stretch_a: no other sequence to build its vocabulary from" in line
    # a second stretch without frames: its vocabulary build fails, and says so before any run
    _tum_folder(data / "stretch_b")
    line = _error(capsys, [*argv, "--out", str(tmp_path / "out")])
    assert "uss-vocab build for stretch_a failed: " in line
    assert not (tmp_path / "out" / "runs").exists()


def _check_cells(table: dict, systems: list[str]) -> None:
    """Every cell's figures are those of its run folder's metrics.json."""
    for row in table["rows"]:
        assert sorted(row["systems"]) == sorted(systems)
        for cell in row["systems"].values():
            metrics = json.loads((Path(cell["run_dir"]) / "metrics.json").read_text())
            summary = metrics["ate_rmse_repeats"]
            values = sorted(r["ate_rmse"] for r in metrics["repeats"])
            assert cell["repeats"] == len(metrics["repeats"]) == table["meta"]["repeats"]
            assert cell["ate_rmse_median"] == summary["median"]
            # the median run: for an even count the lower middle one (a real run)
            assert cell["ate_rmse_median"] == values[(len(values) - 1) // 2]
            assert (cell["ate_rmse_min"], cell["ate_rmse_max"]) == (values[0], values[-1])
            assert cell["spread"] == pytest.approx(values[-1] / values[0])


def _synthetic_argv(
    out: Path, frames: str, size: str, timings: str, strides: str, presets: str, systems: str
) -> list[str]:
    """The table's arguments for synthetic cells only, two repeats each, into ``out``."""
    return ["--no-real", "--synthetic-frames", frames, "--synthetic-size", size,
            "--synthetic-timings", timings, "--repeats", "2", "--strides", strides,
            "--synthetic-presets", presets, "--systems", systems, "--out", str(out)]  # fmt: skip


def test_table_of_synthetic_cells_is_the_run_folders_medians(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    argv = _synthetic_argv(out, "20", "160x120", "global", "1,2", "handheld_rpy",
                           "harness,harness_noback")  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed == (out / "table.md").read_text()
    table = json.loads((out / "table.json").read_text())
    assert [(r["sequence"], r["stride"]) for r in table["rows"]] == [
        ("synthetic handheld_rpy global shutter", 1),
        ("synthetic handheld_rpy global shutter", 2),
    ]
    _check_cells(table, ["harness", "harness_noback"])
    for row in table["rows"]:
        cells = row["systems"]
        assert f"sequence.stride={row['stride']}" in cells["harness"]["command"]
        assert "slam.local_ba=false" in cells["harness_noback"]["command"]
        assert "slam.local_ba=false" not in cells["harness"]["command"]
        assert row["default_over_noback"] == pytest.approx(
            cells["harness"]["ate_rmse_median"] / cells["harness_noback"]["ate_rmse_median"]
        )
        assert row["default_over_orbslam3"] is None
        assert cells["harness"]["frames"] == (20 if row["stride"] == 1 else 10)
    lines = printed.splitlines()
    header = next(i for i, ln in enumerate(lines) if ln.startswith("| sequence"))
    assert lines[header].split(" | ")[2:] == [
        "harness (default)",
        "harness, no back end",
        "default / no back end |",
    ]
    rows = lines[header + 2 : header + 4]
    for line, row in zip(rows, table["rows"], strict=True):
        h = row["systems"]["harness"]
        assert f"| {row['stride']} | {h['ate_rmse_median']:.4f} " in line
        assert line.endswith(f"| {row['default_over_noback']:.2f} |")
    assert "default better than no back end (ratio < 1), synthetic: " in printed

    # a rerun reuses the finished cells (no uss-slam run), unless --force
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/*/*/run.json")}
    assert len(stamps) == 4
    assert main([*argv, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["rows"] == table["rows"]
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps


@pytest.mark.slow
def test_orbslam3_cells_use_a_vocabulary_of_another_seed(tmp_path: Path, capsys) -> None:
    pytest.importorskip("pyorbslam3")
    out = tmp_path / "out"
    argv = _synthetic_argv(out, "30", "320x240", "rolling", "1", "handheld_fast",
                           "harness,orbslam3")  # fmt: skip
    assert main(argv) == 0
    table = json.loads((out / "table.json").read_text())
    _check_cells(table, ["harness", "orbslam3"])
    (row,) = table["rows"]
    orb = row["systems"]["orbslam3"]
    vocab = next(a.split("=", 1)[1] for a in orb["command"] if a.startswith("system.vocabulary="))
    assert Path(vocab).is_file() and "system.repeats=2" in orb["command"]
    sequence = next(a.split("=", 1)[1] for a in orb["command"] if a.startswith("sequence.path="))
    assert sequence.endswith("_seed0")
    # built from the same preset rendered with another seed, never from the scored frames
    other = Path(sequence[: -len("0")] + "1")
    assert table["meta"]["synthetic"]["vocabulary_seed"] == 1
    assert "seed: 1" in (other / "synthetic.yaml").read_text()
    assert "seed: 0" in (Path(sequence) / "synthetic.yaml").read_text()
    assert "handheld_fast" in (Path(sequence) / "synthetic.yaml").read_text()
    assert row["default_over_orbslam3"] == pytest.approx(
        row["systems"]["harness"]["ate_rmse_median"] / orb["ate_rmse_median"]
    )


@pytest.mark.slow
@pytest.mark.skipif(not REAL_DATA.is_dir(), reason=f"no real TUM stretches in {REAL_DATA}")
def test_real_stretches_each_get_a_row_per_stride(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    argv = ["--data", str(REAL_DATA), "--no-synthetic", "--repeats", "1", "--strides", "3"]
    assert main([*argv, "--systems", "harness_noback", "--out", str(out)]) == 0
    table = json.loads((out / "table.json").read_text())
    stretches = sorted(p.name for p in REAL_DATA.iterdir() if (p / "rgb.txt").is_file())
    assert [r["sequence"] for r in table["rows"]] == stretches
    for row in table["rows"]:
        cell = row["systems"]["harness_noback"]
        assert "sequence.camera=fr1" in cell["command"] and row["kind"] == "real"
        metrics = json.loads((Path(cell["run_dir"]) / "metrics.json").read_text())
        assert cell["ate_rmse_median"] == metrics["ate"]["rmse"]
    assert os.path.getsize(out / "table.md") > 0

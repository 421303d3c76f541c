"""``studies/slam_thread_rule.py``: a pre-registered rule on the semantic thread's cells."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from uss_slam.testing.scripts import load_script

rule = load_script(Path(__file__).resolve().parents[2] / "studies" / "slam_thread_rule.py")


def _cell(ates: list[float], tracked: list[float] | None = None) -> dict:
    return {"ate_repeats": ates, "tracked_repeats": tracked or [1.0] * len(ates)}


def _study(folder: Path, sequences: dict[str, dict[str, dict]]) -> Path:
    folder.mkdir(parents=True)
    (folder / "cells.json").write_text(json.dumps(sequences))
    return folder


def _run(capsys, *argv: str) -> str:
    assert rule.main([*argv, "--today", "thread 0.5 s", "--candidate", "thread 0.5 s new"]) == 0
    return capsys.readouterr().out


def test_a_candidate_that_lowers_every_cell_passes(tmp_path: Path, capsys) -> None:
    folder = _study(tmp_path / "s", {
        "walking_xyz_s8": {"per-frame": _cell([0.004, 0.005, 0.006]),
                           "thread 0.5 s": _cell([0.010, 0.012, 0.020]),
                           "thread 0.5 s new": _cell([0.009, 0.011, 0.012])},
        "walking_rpy_s8": {"thread 0.5 s": _cell([0.010, 0.010, 0.010]),
                           "thread 0.5 s new": _cell([0.010, 0.010, 0.010])},
    })  # fmt: skip
    out = _run(capsys, str(folder), "--write-csv", str(tmp_path / "r.csv"))
    assert "| walking_xyz_s8 | 0.0120 (0.0100–0.0200), 100.0 / 100.0 / 100.0% |" in out
    assert "×0.917 | 0.0120 (0.0300) |" in out and "×2.40 → ×2.20 |" in out
    assert "(b) median ratio ×0.958 ≤ ×1.00: met" in out and out.endswith("the set passes\n")
    # the committed CSV gives the same output
    assert _run(capsys, "--csv", str(tmp_path / "r.csv")) == out


@pytest.mark.parametrize(
    ("candidate", "tracked", "failed"),
    [
        ([0.0107, 0.0107, 0.0107], None, "(a) no ratio above ×1.05: failed by s"),
        ([0.0102, 0.0102, 0.0102], None, "(b) median ratio ×1.020 ≤ ×1.00: failed"),
        ([0.005, 0.009, 0.031], None, "(c) every repeat ≤ 1.5 × today's worst: failed by s"),
        (
            [0.009, 0.009, 0.009],
            [1.0, 0.96, 1.0],
            "(d) every repeat's tracked share ≥ today's lowest − 2 points: failed by s",
        ),
    ],
)
def test_each_condition_can_fail(tmp_path: Path, capsys, candidate, tracked, failed) -> None:
    folder = _study(tmp_path / "s", {"s": {
        "thread 0.5 s": _cell([0.010, 0.010, 0.020], [1.0, 0.99, 1.0]),
        "thread 0.5 s new": _cell(candidate, tracked),
    }})  # fmt: skip
    out = _run(capsys, str(folder))
    assert failed in out and out.endswith("the set does not pass\n")


def test_bad_inputs_are_named(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="cells.json: no such file"):
        rule.main([str(tmp_path), "--today", "a", "--candidate", "b"])
    bad = tmp_path / "bad.csv"
    bad.write_text("sequence,ate\n")
    with pytest.raises(SystemExit, match="bad.csv: expected the columns"):
        rule.main(["--csv", str(bad), "--today", "a", "--candidate", "b"])


def test_without_a_candidate_it_gives_the_targets_table(tmp_path: Path, capsys) -> None:
    folder = _study(tmp_path / "s", {
        "a": {"per-frame": _cell([0.004, 0.004, 0.005]), "thread 0.5 s": _cell([0.008] * 3),
              "thread 0 s": _cell([0.0044, 0.0044, 0.005], [1.0, 0.5, 1.0])},
        "b": {"per-frame": _cell([0.010] * 3), "thread 0.5 s": _cell([0.011] * 3)},
    })  # fmt: skip
    assert rule.main([str(folder)]) == 0
    out = capsys.readouterr().out
    assert (
        "| a | 0.0040 (0.0040–0.0050), 100.0 / 100.0 / 100.0% | ×1.10 (100 / 50 / 100%) | ×2.00"
        in out
    )
    assert "thread 0 s: 1 of 2 within ×1.10" in out and "thread 0.5 s: 1 of 2 within ×1.10" in out
    with pytest.raises(SystemExit):
        rule.main([str(folder), "--today", "thread 0.5 s"])

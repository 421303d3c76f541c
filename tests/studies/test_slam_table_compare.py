"""studies/slam_table_compare.py: two tables compared cell by cell, with or without the
no-back-end column."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from uss_slam.testing.scripts import load_script

compare = load_script(Path(__file__).resolve().parents[2] / "studies" / "slam_table_compare.py")


def _table(path: Path, medians: dict[str, float]) -> Path:
    rows = [
        {
            "sequence": "fr1",
            "stride": 1,
            "systems": {k: {"ate_rmse_median": v, "spread": 1.1} for k, v in medians.items()},
        }
    ]
    path.write_text(json.dumps({"rows": rows}))
    return path


def test_tables_without_the_no_back_end_column(tmp_path, monkeypatch, capsys) -> None:
    before = _table(tmp_path / "a.json", {"harness": 0.010})
    after = _table(tmp_path / "b.json", {"harness": 0.012})
    monkeypatch.setattr(sys, "argv", ["slam_table_compare.py", str(before), str(after)])
    compare.main()
    out = capsys.readouterr().out
    assert "| fr1 | 1 | harness | 0.0100 ×1.10 | 0.0120 ×1.10 | 1.200 |" in out
    assert "more than 10% worse: 1" in out
    assert "neither table has the no-back-end column" in out


def test_tables_with_it(tmp_path, monkeypatch, capsys) -> None:
    before = _table(tmp_path / "a.json", {"harness": 0.010, "harness_noback": 0.0095})
    after = _table(tmp_path / "b.json", {"harness": 0.009})
    monkeypatch.setattr(sys, "argv", ["slam_table_compare.py", str(before), str(after)])
    compare.main()
    assert "> 1.02: before 1, after 0 of 1 rows" in capsys.readouterr().out

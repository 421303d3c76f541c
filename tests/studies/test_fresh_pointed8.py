"""The eighth set's split by the families named to the engineer fixing code."""

from __future__ import annotations

import json

from shared_helpers import STUDIES, study

_SPLIT = study("fresh_pointed8")
main, pointed_family = _SPLIT.main, _SPLIT.pointed_family


def test_families_are_recognised_from_id_env_and_argv():
    assert pointed_family("eval8-abbrev-s | uss-eval | error | - | - | --s | x") is not None
    assert pointed_family("x | uss-traj | ok | - | ULIMIT_N=24 | - | ate a b") is not None
    assert pointed_family('x | uss-slam | ok | - | - | - | "out_dir=${{oc.env:N,o}}"') is not None
    assert pointed_family("x | uss-traj | hup:0.8 | - | - | - | ate a b") is not None
    assert pointed_family("x | uss-synth | gterm:4.0 | - | - | - | voc") is None
    assert pointed_family("x | uss-slam | error | - | - | - | -cn nope") is None


def test_split_counts_every_case_once(tmp_path, capsys):
    cases = tmp_path / "cases.txt"
    cases.write_text(
        "# header\n"
        "a-abbrev-x | uss-synth | ok | - | - | - | voc\n"
        "b-plain | uss-synth | ok | - | - | - | voc\n"
        "c-plain | uss-traj | error | - | - | --x | ate\n",
        encoding="utf-8",
    )
    outcomes = [
        {"id": "a-abbrev-x", "verdict": "poor"},
        {"id": "b-plain", "verdict": "good"},
        {"id": "c-plain", "verdict": "bad"},
    ]
    results = tmp_path / "results.json"
    results.write_text(json.dumps({"outcomes": outcomes}), encoding="utf-8")
    assert main([str(cases), str(results)]) == 0
    out = capsys.readouterr().out
    assert "every case: 3 counted, 1 good, 1 poor, 1 bad (33.3% good)" in out
    assert "named to the fixer: 1 counted, 0 good, 1 poor, 0 bad (0.0% good)" in out
    assert "not named to the fixer: 2 counted, 1 good, 0 poor, 1 bad (50.0% good)" in out
    assert "poor a-abbrev-x: argparse abbreviations of long flags" in out


def test_the_set_splits_into_both_groups():
    lines = (STUDIES / "fresh_cases8.txt").read_text(encoding="utf-8").splitlines()
    cases = [line for line in lines if line.strip() and not line.startswith("#")]
    named = [line for line in cases if pointed_family(line)]
    assert 0 < len(named) < len(cases)

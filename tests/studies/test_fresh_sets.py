"""The held-out sets that need no setup of their own (studies/fresh_cases10.txt and later):
every case names known setups and forms with a made-up world's paths, and the screen compared
each set with every set before it (no case is run here)."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest
from shared_helpers import study

ROOT = Path(__file__).resolve().parents[2]
STUDIES = ROOT / "studies"

SETS = {10: ((22, 26), (200, 230)), 11: ((16, 19), (150, 165))}
"""Set number -> (cases per script, cases in all), the ranges its writer fixed."""


@pytest.mark.parametrize("number", list(SETS))
def test_a_sets_templates_form(fresh, number: int) -> None:
    """Every case of the set names known setups, has a known expectation, its argv,
    environment and expected words form with the world's paths, a quoted argument stays one,
    an error case names what its line must hold, and each script has its share of cases,
    about half of them valid inputs."""
    (low, high), (least, most) = SETS[number]
    cases = fresh.read_cases(STUDIES / f"fresh_cases{number}.txt")
    names = ("W", "seq", "seq2", "voc", "ckpt", "onnx", "onnx2", "gt", "est", "vocab", "slam")
    paths = {**{n: f"/w/{n}" for n in names}, "C": "/c", "R": "/r", "tum": "/t", **fresh.LONG}
    assert len({c.id for c in cases}) == len(cases)
    expects = ("ok", "warn", "error", "pipe", "jobs")
    for case in cases:
        assert case.id.startswith(f"{case.prog.removeprefix('uss-')}{number}-"), case.id
        assert all(s in fresh.SETUPS for s in case.setup), case.id
        assert case.expect in expects or case.expect.startswith(fresh.SIGNALLED), case.id
        argv = fresh._argv(case, paths)
        assert argv and not any("{" in a for a in argv), case.id
        for value in case.env.values():
            value.format(**paths)
        says = [s.format(**paths) for s in case.says]
        assert bool(says) == (case.expect == "error"), case.id
        for quoted in re.findall(r'"([^"]*)"', case.argv):
            assert quoted.format(**paths) in argv, case.id
    counts = Counter(c.prog for c in cases)
    assert len(counts) == 9 and all(low <= n <= high for n in counts.values()), counts
    valid = sum(c.expect == "ok" for c in cases)
    assert least <= len(cases) <= most and 0.4 <= valid / len(cases) <= 0.6, (len(cases), valid)


@pytest.mark.parametrize("number", list(SETS))
def test_the_screen_held_every_set_before_a_set(number: int) -> None:
    """The screen compares a set only with the sets listed before its own name: for each set,
    every earlier one, in order."""
    screen_cases = study("screen_cases")
    name, earlier = f"fresh_cases{number}.txt", list(screen_cases.EARLIER)
    before = earlier[: earlier.index(name)] if name in earlier else earlier  # (the newest)
    assert before == ["fresh_cases.txt", *(f"fresh_cases{k}.txt" for k in range(2, number))]
    assert all((STUDIES / name).is_file() for name in before)

"""studies/fresh_cases10.txt: every case names known setups and forms with a made-up world's
paths (the tenth set needs no new setup; no case is run here)."""

from __future__ import annotations

import re
import sys
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
STUDIES = ROOT / "studies"


@pytest.fixture(scope="module")
def fresh():
    sys.path.insert(0, str(STUDIES))
    try:
        import fresh_cases

        yield fresh_cases
    finally:
        sys.path.remove(str(STUDIES))


def test_the_tenth_sets_templates_form(fresh) -> None:
    """Every case of studies/fresh_cases10.txt names known setups, has a known expectation, its
    argv, environment and expected words form with the world's paths, a quoted argument stays
    one, an error case names what its line must hold, and each script has 22 to 26 cases,
    about half of them valid inputs."""
    cases = fresh.read_cases(STUDIES / "fresh_cases10.txt")
    names = ("W", "seq", "seq2", "voc", "ckpt", "onnx", "onnx2", "gt", "est", "vocab", "slam")
    paths = {**{n: f"/w/{n}" for n in names}, "C": "/c", "R": "/r", "tum": "/t", **fresh.LONG}
    assert len({c.id for c in cases}) == len(cases)
    expects = ("ok", "warn", "error", "pipe", "jobs")
    for case in cases:
        assert case.id.startswith(case.prog.removeprefix("uss-") + "10-"), case.id
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
    assert len(counts) == 9 and all(22 <= n <= 26 for n in counts.values()), counts
    valid = sum(c.expect == "ok" for c in cases)
    assert 200 <= len(cases) <= 230 and 0.4 <= valid / len(cases) <= 0.6, (len(cases), valid)


def test_the_screen_holds_every_earlier_set() -> None:
    """The screen compares the tenth set with all nine sets before it (it screens a set only
    against the sets listed before its own name)."""
    sys.path.insert(0, str(STUDIES))
    try:
        import screen_cases
    finally:
        sys.path.remove(str(STUDIES))
    before = screen_cases.EARLIER[: screen_cases.EARLIER.index("fresh_cases10.txt")]
    assert before[-1] == "fresh_cases9.txt"
    assert all((STUDIES / name).is_file() for name in before)
    assert len(before) == 9

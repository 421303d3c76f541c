"""studies/fresh_cases.py's classification of a case by docs/errors.md: a successful rerun into
a script's own output folder replaces the files it writes there (not data lost), a file gone
or a file changed by a failed run or by an output-file script without --overwrite is."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

STUDIES = Path(__file__).resolve().parents[2] / "studies"


@pytest.fixture(scope="module")
def fresh():
    sys.path.insert(0, str(STUDIES))
    try:
        import fresh_cases

        yield fresh_cases
    finally:
        sys.path.remove(str(STUDIES))


def _case(fresh, prog: str, expect: str, argv: str = "--out {C}/e"):
    return fresh.Case("c", prog, expect, (), {}, (), argv)


@pytest.mark.parametrize(
    ("prog", "expect", "code", "after", "verdict"),
    [
        ("uss-eval", "ok", 0, {"e/eval.md": "new", "e/eval.json": "new"}, "good"),  # rerun
        ("uss-eval", "ok", 0, {"e/eval.json": "new"}, "bad"),  # its eval.md gone
        ("uss-eval", "error", 1, {"e/eval.md": "new"}, "bad"),  # a failed run changed it
        ("uss-vocab", "ok", 0, {"e/eval.md": "new"}, "bad"),  # a file output: --overwrite
    ],
)
def test_rerun_into_own_folder(fresh, prog, expect, code, after, verdict) -> None:
    before = {"e/eval.md": "old"}
    err = "" if code == 0 else f"{prog}: error: --out: bad"
    got, _ = fresh.classify(_case(fresh, prog, expect), code, err, before, after, {})
    assert got == verdict

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


def test_the_screen_flags_a_generated_case_and_an_earlier_one(fresh, tmp_path) -> None:
    """studies/screen_cases.py: a case that is a generated argparse value (``--images 0``), one
    that repeats an earlier set's case and a new one; only the first two are repeats."""
    import screen_cases

    cases = tmp_path / "cases.txt"
    cases.write_text(
        "a | uss-synth | error | - | - | --images | voc --images 0 --size 48x32 --out {C}/v --quiet\n"
        "b | uss-traj | ok | - | - | - | ate {gt} {est} --align SE3\n"
        "c | uss-traj | ok | - | - | - | ate {est} {gt} --align none --bands 0.125\n"
    )
    found = screen_cases.screen(cases)
    assert any(f.startswith("a: generated argparse case --images 0") for f in found), found
    assert any(f.startswith("b: ") for f in found), found
    assert not any(f.startswith("c: ") for f in found), found

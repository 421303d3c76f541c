"""The ninth set's split by the families the engineer fixing code looked at."""

from __future__ import annotations

from shared_helpers import STUDIES, made_up_split, study

_SPLIT = study("fresh_pointed9")
main, POINTED = _SPLIT.main, _SPLIT.POINTED


def family(line: str) -> str | None:
    return study("fresh_pointed8").pointed_family(line, POINTED)


def test_families_are_recognised_from_env_and_argv():
    assert family("a | uss-traj | error | - | - | --plot | ate {gt} {est} --plot {C}/p.gif")
    assert family("b | uss-slam | ok | - | - | - | -m sequence.path={seq},{seq2}")
    assert family("c | uss-eval | warn | - | STDOUT=full | stdout | {onnx} --out {C}/e")
    assert family("d | uss-vocab | ok | seqcopy | - | - | build {C}/seq --out {C}/seq/v.txt")
    assert family("e | uss-export | ok | - | TORCH_HOME={C}/t | - | EXPORT name=h") is None
    assert family("f | uss-traj | error | - | - | --plot | rpe {gt} {est} --plot {C}/p.png") is None


def test_split_of_a_made_up_run(tmp_path, capsys):
    out = made_up_split(
        main,
        tmp_path,
        capsys,
        "a | uss-traj | error | - | - | --plot | ate {gt} {est} --plot {C}/p.gif",
    )
    assert "poor a: --plot's formats" in out


def test_the_set_splits_into_both_groups():
    lines = (STUDIES / "fresh_cases9.txt").read_text(encoding="utf-8").splitlines()
    cases = [line for line in lines if line.strip() and not line.startswith("#")]
    named = [line for line in cases if family(line)]
    assert 0 < len(named) < len(cases) // 5

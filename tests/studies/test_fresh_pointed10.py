"""The tenth set's split by the families the engineer fixing code looked at (made-up cases: the
split was written without reading the set)."""

from __future__ import annotations

from shared_helpers import made_up_split, study

_SPLIT = study("fresh_pointed10")
main, POINTED = _SPLIT.main, _SPLIT.POINTED


def family(line: str) -> str | None:
    return study("fresh_pointed8").pointed_family(line, POINTED)


def test_families_are_recognised_from_expect_env_and_argv():
    assert family("a | uss-vocab | usr1:3 | seq | - | - | build {seq} --out {C}/v.txt")
    assert family("b | uss-slam | galrm:2 | - | - | - | sequence.path={seq} out_dir={C}/r")
    assert family(
        "c | uss-eval | error | - | - | --repeats | compare {onnx} {onnx2} --slam --repeats 1"
    )
    assert family("d | uss-slam | error | - | - | --package | sequence.path={seq} -p slam")
    assert family("e | uss-train | error | - | - | model/net | model/net=null")
    assert family("f | uss-traj | error | - | - | --delta | rpe {gt} {est} --delta inf")
    assert family(
        "g | uss-slam | error | - | - | slam.orb.scale_factor | slam.orb.scale_factor=nan"
    )
    assert family("h | uss-traj | error | - | - | /dev/null | ate {gt} /dev/null")
    assert family(
        "l | uss-slam | error | - | - | slam.workers | slam.workers=${oops} out_dir={C}/o"
    )
    assert family("m | uss-slam | error | - | - | glob | -m segmenter=glob(zz*) out_dir={C}/o")
    assert family("i | uss-export | ok | - | TORCH_HOME={C}/t | - | EXPORT name=h") is None
    assert family("j | uss-slam | ok | - | - | - | sequence.path={seq} slam.workers=2") is None
    assert family("k | uss-slam | ok | - | - | - | out_dir={C}/information") is None


def test_split_of_a_made_up_run(tmp_path, capsys):
    out = made_up_split(
        main, tmp_path, capsys, "a | uss-slam | error | - | - | segmenter | segmenter=null"
    )
    assert "poor a: a config group given null or a number" in out

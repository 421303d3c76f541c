"""The generated matrix of the argparse console scripts (``uss-synth``, ``uss-traj``,
``uss-vocab``, ``uss-eval`` and ``uss-eval compare``, ``uss-demo``): their parsers are walked
(:func:`uss_slam.core.arguments.bad_arguments`) and every number option's wrong type and
crossed bounds, every unknown choice, and every list of names' empty, unknown and repeated
item is run as the console script in this process. The Hydra scripts' keys are generated from
their schemas in ``tests/test_cli_matrix.py``; together every script is covered, and a new
option or key enters without a list to edit.

The contract (docs/errors.md): exit code 2 (an argparse usage error), argparse's usage and then
one line ``<prog>[ <command>]: error: argument <flag>: expected ...``, no traceback, nothing
written into the folder the script runs in.
"""

from __future__ import annotations

import argparse
import importlib
import logging
from collections.abc import Callable
from pathlib import Path

import pytest
from test_cli_matrix import CHECKERS, run_console_script, snapshot
from test_path_families import PATH_ARGS, PathArg

from uss_slam.core.arguments import Arg, BadArgument, bad_arguments, path_argument
from uss_slam.core.launch import SCRIPTS

Parser = Callable[[], argparse.ArgumentParser]


def argparse_scripts() -> list[tuple[str, tuple[str, ...], Parser]]:
    """``(prog, commands, build_parser)`` of every console script with an argparse parser
    (its module's ``build_parser``) and of its subcommands with a parser of their own (the
    module's ``COMMANDS``: name -> module)."""
    found = []
    for prog, module_name in SCRIPTS.items():
        module = importlib.import_module(module_name)
        if hasattr(module, "build_parser"):
            found.append((prog, (), module.build_parser))
        for name, sub in getattr(module, "COMMANDS", {}).items():
            found.append((prog, (name,), importlib.import_module(sub).build_parser))
    return found


SCRIPT_PARSERS = argparse_scripts()
BAD = [
    (prog, bad)
    for prog, commands, build in SCRIPT_PARSERS
    for bad in bad_arguments(build(), commands)
]


def test_every_console_script_is_generated_from_its_parser_or_its_schema() -> None:
    """Each console script of pyproject's [project.scripts] (core/launch.py's SCRIPTS) is in
    this matrix (argparse) or in the schema matrix (Hydra)."""
    argparse_progs = {prog for prog, _, _ in SCRIPT_PARSERS}
    assert set(SCRIPTS) == argparse_progs | set(CHECKERS), (argparse_progs, set(CHECKERS))
    assert not argparse_progs & set(CHECKERS)


def test_every_number_option_declares_its_range() -> None:
    """A number option is typed by :class:`~uss_slam.core.arguments.Arg` (its range), never a
    bare ``int`` or ``float`` that takes 0, -1 or 10**9 alike."""
    undeclared = [f"{prog} {bad.id}" for prog, bad in BAD if bad.kind == "undeclared"]
    assert undeclared == []


def test_the_matrix_has_cases_of_every_kind() -> None:
    kinds = {bad.kind for _, bad in BAD}
    assert {"type", "range", "choice", "duplicate", "empty"} <= kinds, kinds
    assert len(BAD) >= 60, len(BAD)


@pytest.mark.parametrize(
    ("prog", "bad"),
    [pytest.param(p, b, id=f"{p} {b.id}") for p, b in BAD if b.kind != "undeclared"],
)
def test_generated_argument_is_one_usage_line(
    prog: str, bad: BadArgument, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(logging, "raiseExceptions", False)
    (tmp_path / "earlier.txt").write_text("an earlier output\n")
    before = snapshot(tmp_path)
    code, _, err = run_console_script(
        prog, [*bad.commands, bad.flag, bad.value], monkeypatch, capsys
    )
    lines = err.strip().splitlines()
    assert "Traceback" not in err, err
    assert code == 2, err
    head = " ".join((prog, *bad.commands))
    assert lines[-1].startswith(f"{head}: error: argument "), err
    assert bad.flag in lines[-1], err
    assert "expected" in lines[-1] or "choose from" in lines[-1], err  # argparse's choices
    if bad.value in ("nan", "inf"):  # a number, but not finite: the line says which
        assert "expected a finite number" in lines[-1], err
    assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), err
    assert snapshot(tmp_path) == before


def _every_action() -> list[tuple[str, tuple[str, ...], argparse.Action]]:
    """``(prog, commands, action)`` of every argument of every parser and subparser."""
    found = []

    def walk(prog: str, parser: argparse.ArgumentParser, commands: tuple[str, ...]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(prog, sub, (*commands, name))
            else:
                found.append((prog, commands, action))

    for prog, commands, build in SCRIPT_PARSERS:
        walk(prog, build(), commands)
    return found


def _path_actions() -> list[tuple[str, tuple[str, ...], str]]:
    """``(prog, commands, flag or '')`` of every path-typed argument of every parser."""
    return [
        (prog, commands, action.option_strings[-1] if action.option_strings else "")
        for prog, commands, action in _every_action()
        if action.type in (Path, path_argument)
    ]


def test_every_path_argument_is_in_the_path_families() -> None:
    """Each path option of each argparse parser has a row in ``tests/test_path_families.py``
    (every family then runs on it): an option by its flag, a positional one by its
    subcommand."""

    def command(a: PathArg) -> str:
        first = a.argv.split()[0]
        return first if first.isidentifier() else ""

    rows = {(a.prog, command(a), a.key or "") for a in PATH_ARGS}
    missing = [
        f"{prog} {' '.join(commands)} {flag or '(positional)'}"
        for prog, commands, flag in _path_actions()
        if (prog, commands[0] if commands else "", flag) not in rows
    ]
    assert missing == [], missing


def test_every_path_argument_refuses_the_empty_string() -> None:
    """Every path option and argument is typed :func:`path_argument`: ``--out ""`` is one usage
    line naming the flag, not the current folder (``Path("")``)."""
    plain = [(prog, action.dest) for prog, _, action in _every_action() if action.type is Path]
    assert plain == [], plain
    for text in ("", "  "):
        with pytest.raises(argparse.ArgumentTypeError, match="expected a path, got"):
            path_argument(text)
    assert path_argument("a b") == Path("a b")


def test_names_refuse_an_empty_name() -> None:
    """``--dynamic person,,chair`` (a name left out between the commas) is refused, as ``,``
    is; spaces around a name are not a name."""
    from uss_slam.core.arguments import Names

    names = Names(("person", "chair"))
    assert names(" person , chair ") == ["person", "chair"]
    for text in ("person,,chair", "person,", ",", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="expected comma-separated names"):
            names(text)


def test_arg_refuses_each_bound_and_takes_the_bounds() -> None:
    arg = Arg(int, __import__("uss_slam.core.ranges", fromlist=["Range"]).Range(min=1, max=3))
    assert [arg("1"), arg("3")] == [1, 3]
    for text in ("0", "4", "1.5", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="expected an integer >= 1"):
            arg(text)


# ------------------------------------------------------------------------------ given twice


def _a_valid_value(action: argparse.Action) -> list[str]:
    """Tokens that ``action`` (a value option) takes: its first choice, else the first of a
    few candidates its type converts (a number in its range, a path, a name)."""
    if action.choices:
        return [str(next(iter(action.choices)))]
    names = getattr(action.type, "choices", None)
    candidates = [*(names[:1] if names else []), "1", "0.5", "2", "100", "x.png", "walking_xyz",
                  "64x48"]  # fmt: skip
    for text in candidates:
        try:
            if action.type is not None:
                action.type(text)
        except (argparse.ArgumentTypeError, ValueError, TypeError):
            continue
        return [text] * (action.nargs if isinstance(action.nargs, int) else 1)
    raise AssertionError(f"no candidate value for {action.option_strings}")


def _value_options() -> list[tuple[str, tuple[str, ...], str, list[str]]]:
    """``(prog, commands, flag, a valid value)`` of every value option of every parser."""
    from uss_slam.core.arguments import ONCE_KINDS

    return [
        (prog, commands, action.option_strings[-1],
         [] if action.nargs == 0 else _a_valid_value(action))
        for prog, commands, action in _every_action()
        if action.option_strings and isinstance(action, ONCE_KINDS)
    ]  # fmt: skip


VALUE_OPTIONS = _value_options()


@pytest.mark.parametrize(
    ("prog", "commands", "flag", "value"),
    VALUE_OPTIONS,
    ids=[f"{p} {' '.join(c)} {f}".replace("  ", " ") for p, c, f, _ in VALUE_OPTIONS],
)
def test_a_value_option_given_twice_is_one_usage_line(
    prog: str,
    commands: tuple[str, ...],
    flag: str,
    value: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    """``--out a --out b``: argparse would keep the second without a word. Every value option
    of every argparse script is refused the second time (exit code 2, the usage line naming
    the flag and both uses), before any work."""
    monkeypatch.chdir(tmp_path)
    code, _, err = run_console_script(
        prog, [*commands, flag, *value, flag, *value], monkeypatch, capsys
    )
    lines = err.strip().splitlines()
    assert code == 2, err
    assert lines[-1].startswith(f"{' '.join((prog, *commands))}: error: argument "), err
    assert f"{flag}: given twice ({flag}" in lines[-1], err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["-1e-2", "-2.5E+1", "-3", "-0.5", "-.5"])
def test_a_negative_number_in_any_spelling_is_a_value_not_an_option(value: str) -> None:
    """argparse's own pattern took ``-1e-2`` for an option (``--offset: expected one
    argument``); every argparse script's parser takes it as the number it is."""
    from uss_slam.slam_eval.scoring import traj_cli

    args = traj_cli.build_parser().parse_args(["ate", "gt.txt", "est.txt", "--offset", value])
    assert args.offset == float(value)


def test_an_option_is_still_an_option_after_a_value_option() -> None:
    from uss_slam.slam_eval.scoring import traj_cli

    with pytest.raises(SystemExit):  # "-e" is no number: argparse still reads it as an option
        traj_cli.build_parser().parse_args(["ate", "gt.txt", "est.txt", "--offset", "-e"])


def test_the_value_options_are_many_and_flags_and_lists_may_repeat() -> None:
    assert len(VALUE_OPTIONS) >= 40, len(VALUE_OPTIONS)
    from uss_slam.pipelines.evaluate import cli

    args = cli.build_parser().parse_args(["m.onnx", "--sequence", "a", "--sequence", "b"])
    assert [str(s) for s in args.sequence] == ["a", "b"]  # an append option


ARGPARSE_PATHS = [  # (a path given as a word of its own, not inside a KEY=VALUE)
    a for a in PATH_ARGS if a.prog in {p for p, _, _ in SCRIPT_PARSERS} and "{P}" in a.argv.split()
]


@pytest.mark.parametrize(
    "arg",
    ARGPARSE_PATHS,
    ids=[f"{a.prog}-{a.name or a.key or a.argv.split()[0]}" for a in ARGPARSE_PATHS],
)
def test_a_path_starting_with_a_dash_is_named_with_how_to_write_it(
    arg: PathArg, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """argparse reads ``-x.d`` as an option it does not have, and its line named what was then
    missing (``the following arguments are required: EST``, ``argument --plot: expected one
    argument``), not the path."""
    fields = {"tmp": str(tmp_path), "seq": "s", "gt": "gt.txt", "m": "m.onnx"}
    argv = [word.format(P="-x.d", **fields) for word in arg.argv.split()]
    monkeypatch.chdir(tmp_path)
    code, _, err = run_console_script(arg.prog, argv, monkeypatch, capsys)
    assert code == 2, err
    assert (
        err.strip()
        .splitlines()[-1]
        .endswith(
            ": error: -x.d: read as an option, and there is none of that name; write a path "
            "starting with '-' as ./-x.d"
        )
    ), err

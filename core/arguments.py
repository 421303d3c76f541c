"""The argparse console scripts' numbers and lists, declared as the Hydra scripts' schemas
declare theirs: an option's ``type`` is an :class:`Arg` holding its :class:`~.ranges.Range`,
so that a bad value is argparse's one usage line naming the flag (``argument --stride:
expected an integer >= 1, got '0'``, exit code 2) and the test matrix generates its bad values
from the parsers themselves (:func:`bad_arguments`): a new option enters it without an edit.

Torch-free and OmegaConf-free (floor 0).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import re
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .paths import home_expanded
from .ranges import MAX_THREADS, THREADS_PER_CPU, Range


def _bounds(range_: Range) -> str:
    parts = []
    for op, bound in ((">=", range_.min), (">", range_.gt), ("<=", range_.max), ("<", range_.lt)):
        if bound is not None:  # an integer bound in full (a seed's 4294967295, not 4.29e+09)
            parts.append(f"{op} {bound}" if isinstance(bound, int) else f"{op} {bound:g}")
    return " and ".join(parts)


@dataclass(frozen=True)
class Arg:
    """An argparse ``type``: a number of ``kind`` (int or float, finite) within ``range``;
    ``why`` explains the bound (``'4 per CPU'``)."""

    kind: type
    range: Range = Range()  # noqa: A003
    why: str = ""

    def expected(self) -> str:
        what = "an integer" if self.kind is int else "a number"
        bounds = _bounds(self.range)
        return f"{what} {bounds}".strip() + (f" ({self.why})" if self.why else "")

    def __call__(self, text: str) -> Any:
        try:
            value = self.kind(text)
        except ValueError:
            value = None
        if value is None:
            raise argparse.ArgumentTypeError(f"expected {self.expected()}, got {text!r}")
        if self.kind is float and not math.isfinite(value):  # (inf is > 0: say what is wrong)
            finite = self.expected().replace("a number", "a finite number", 1)
            raise argparse.ArgumentTypeError(f"expected {finite}, got {text!r}")
        r = self.range
        if ((r.min is not None and value < r.min) or (r.max is not None and value > r.max)
                or (r.gt is not None and value <= r.gt) or (r.lt is not None and value >= r.lt)):  # fmt: skip
            raise argparse.ArgumentTypeError(f"expected {self.expected()}, got {text!r}")
        return value

    @property
    def __name__(self) -> str:  # argparse names the type in "invalid <name> value"
        return self.kind.__name__


def number(kind: type = int, why: str = "", **bounds: float) -> Arg:
    """``type=number(int, min=1)``: an :class:`Arg` (``bounds``: min, max, gt, lt)."""
    return Arg(kind, Range(**bounds), why)


def path_argument(text: str) -> Path:
    """The argparse ``type`` of every path option and argument: a path, never the empty string
    (``Path("")`` is the current folder: ``--out ""`` would write there); what the path is
    checked for is the path layer's (``core/paths.py``). A ``~`` or ``~user`` that starts it is
    expanded as a shell expands it (:func:`uss_slam.core.paths.home_expanded`: ``--out=~/x``
    and a quoted ``'~/x'`` reach the script as they are)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a path, got {text!r}")
    text = home_expanded(text)
    path = _Given(text)
    path.trailing_slash = len(text) > 1 and text.endswith("/")  # `Path` drops it: a folder
    return path


class _Given(type(Path())):  # type: ignore[misc]
    """A path as typed: ``trailing_slash`` remembers a final ``/`` (``--out DIR/vv/`` names a
    folder; the path layer refuses it where a file is expected)."""

    trailing_slash = False


THREADS_ARG = Arg(int, Range(min=1, max=MAX_THREADS), f"{THREADS_PER_CPU} per CPU")
"""The type of every thread-count option: bounded by the machine (:data:`~.ranges.MAX_THREADS`)."""


def of_field(schema: type, name: str) -> Arg:
    """The :class:`Arg` of a schema dataclass's number field (its ``ranged`` metadata), so that
    a script whose options are also a schema declares each range once."""
    found = {f.name: f for f in dataclasses.fields(schema)}[name]
    tp = str(found.type)
    kind = float if "float" in tp else int
    keys = ("min", "max", "gt", "lt")
    bounds = {k: v for k, v in found.metadata.items() if k in keys and v is not None}
    if kind is int and bounds.get("max") == MAX_THREADS:
        return THREADS_ARG
    return Arg(kind, Range(**bounds))


@dataclass(frozen=True)
class Names:
    """An argparse ``type``: comma-separated names among ``choices``, each once, at least one,
    none empty (``--dynamic person,chair``; spaces around a name are dropped); returns the
    list."""

    choices: tuple[str, ...]

    def __call__(self, text: str) -> list[str]:
        names = [n.strip() for n in text.split(",")]
        expected = f"expected comma-separated names of {', '.join(self.choices)}, each once"
        unknown = [n for n in names if n not in self.choices]
        if unknown:  # an empty name too (``person,,chair``: a name left out?)
            raise argparse.ArgumentTypeError(f"{expected}, got {text!r}")
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise argparse.ArgumentTypeError(f"{expected} ({twice[0]!r} is listed twice)")
        return names

    @property
    def __name__(self) -> str:
        return "names"


# ---------------------------------------------------------------- the generated bad values


@dataclass(frozen=True)
class BadArgument:
    """``value`` for ``flag`` after the subcommands ``commands`` is wrong in ``kind`` (``type``,
    ``range``, ``choice``, ``duplicate``, ``empty``; ``undeclared``: a number option whose
    type declares no range, which the matrix reports as a fault of the parser)."""

    commands: tuple[str, ...]
    flag: str
    kind: str
    value: str

    @property
    def id(self) -> str:
        return " ".join((*self.commands, self.flag, repr(self.value)))


def _crossed(arg: Arg) -> list[str]:
    step = 1 if arg.kind is int else 1e-9
    r, out = arg.range, []
    if r.min is not None:
        out.append(r.min - (1 if arg.kind is int else max(1e-9, abs(r.min) * 1e-6)))
    if r.gt is not None:
        out.append(r.gt)
    if r.max is not None:
        out.append(r.max + (1 if arg.kind is int else max(step, abs(r.max) * 1e-6)))
    if r.lt is not None:
        out.append(r.lt)
    return [str(int(v)) if arg.kind is int else repr(float(v)) for v in out]


def _of_action(action: argparse.Action, commands: tuple[str, ...]) -> Iterator[BadArgument]:
    flag = action.option_strings[-1] if action.option_strings else action.dest
    t = action.type
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        yield BadArgument(commands, flag, "choice", "no_such_choice")
    if isinstance(t, Arg):
        yield BadArgument(commands, flag, "type", "abc")
        if t.kind is float:
            yield from (BadArgument(commands, flag, "type", v) for v in ("nan", "inf"))
        yield from (BadArgument(commands, flag, "range", v) for v in _crossed(t))
    elif isinstance(t, Names):
        yield BadArgument(commands, flag, "choice", "no_such_name")
        yield BadArgument(commands, flag, "empty", ",")
        yield BadArgument(commands, flag, "duplicate", f"{t.choices[0]},{t.choices[0]}")
    elif t in (int, float):
        yield BadArgument(commands, flag, "undeclared", "abc")


def bad_arguments(
    parser: argparse.ArgumentParser, commands: tuple[str, ...] = ()
) -> Iterator[BadArgument]:
    """Every :class:`BadArgument` of ``parser`` and of its subcommands' parsers: for each number
    option a wrong type and each bound crossed, an unknown choice, and for a list of names an
    empty list, an unknown name and a name listed twice."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from bad_arguments(sub, (*commands, name))
        elif not isinstance(action, argparse._HelpAction):
            yield from _of_action(action, commands)


ONCE_KINDS = (argparse._StoreAction, argparse.BooleanOptionalAction)
"""The option actions whose second use would replace the first without a word (``--out a
--out b``; ``--x --no-x``); an ``append`` option (``--sequence``) is given as often as wanted,
and a flag (``--quiet``) means the same however often it is given."""


NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")
"""What argparse takes for a negative number, not an option: ``-2``, ``-0.5``, ``-.5``, and in
scientific notation, ``-1e-2`` (argparse's own pattern stops at ``-1.5``, so ``--offset -1e-2``
was "expected one argument")."""


def given_once(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``parser`` (and its subcommands' parsers), each of whose value options refuses being
    given twice on one command line with argparse's usage line (exit code 2): ``argument
    --out: given twice (--out /a and --out /b); expected it once``; a negative number in
    scientific notation is a value (:data:`NEGATIVE_NUMBER`). Every argparse console script's
    ``build_parser`` returns its parser through this."""
    parser._negative_number_matcher = NEGATIVE_NUMBER  # type: ignore[attr-defined]
    _dash_paths_named(parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                given_once(sub)
        elif action.option_strings and type(action) in ONCE_KINDS:
            action.__class__ = _ONCE[type(action)]
    return parser


_DASH_CONSEQUENCES = (
    "the following arguments are required",
    "expected one argument",
    "expected at least one argument",
    "unrecognized arguments",
)
"""argparse's errors that an unknown option read in place of a value leads to."""


def _dash_paths_named(parser: argparse.ArgumentParser) -> None:
    """A path starting with ``-`` (``uss-traj ate -gt.txt est.txt``) is read by argparse as an
    option it does not have, and its error named what was missing instead (``the following
    arguments are required: EST``): the error line names that path and how to write it,
    ``-gt.txt: read as an option, and there is none of that name; write a path starting with
    '-' as ./-gt.txt``. A token counts as such a path when it exists or holds a
    ``.`` or ``/`` (a mistyped option, ``--verbos``, keeps argparse's own line)."""
    parse, error = parser.parse_known_args, parser.error

    def parse_known_args(args: Sequence[str] | None = None, namespace: Any = None) -> Any:
        parser._given_args = list(sys.argv[1:] if args is None else args)  # type: ignore[attr-defined]
        return parse(args, namespace)

    def dash_error(message: str) -> Any:
        if any(consequence in message for consequence in _DASH_CONSEQUENCES):
            for token in getattr(parser, "_given_args", []):
                if token == "--":
                    break
                if _dash_path(parser, token):
                    message = (
                        f"{token}: read as an option, and there is none of that name; write a "
                        f"path starting with '-' as ./{token}"
                    )
                    break
        return error(message)

    parser.parse_known_args = parse_known_args  # type: ignore[method-assign]
    parser.error = dash_error  # type: ignore[method-assign]


def _dash_path(parser: argparse.ArgumentParser, token: str) -> bool:
    if not token.startswith("-") or token == "-" or NEGATIVE_NUMBER.match(token):
        return False
    name = token.split("=", 1)[0]
    if any(o == name or o.startswith(name) for o in parser._option_string_actions):
        return False  # one of the parser's options, or an abbreviation of one
    return os.path.lexists(token) or "." in token or "/" in token


def _shown(option: str | None, values: Any) -> str:
    if values is None:
        return str(option)
    items = values if isinstance(values, list) else [values]
    return " ".join([str(option), *(str(v) for v in items)])


def _once(kind: type[argparse.Action]) -> type[argparse.Action]:
    class Once(kind):  # type: ignore[misc,valid-type]
        """``kind`` that refuses a second use in the same parse (the same namespace)."""

        def __call__(self, parser: Any, namespace: Any, values: Any, option: Any = None) -> None:
            first = getattr(self, "_given", None)
            if first is not None and first[0] is namespace:
                raise argparse.ArgumentError(
                    self,
                    f"given twice ({first[1]} and {_shown(option, values)}); expected it once "
                    "(the second would replace the first without a word)",
                )
            self._given = (namespace, _shown(option, values))
            super().__call__(parser, namespace, values, option)

    Once.__name__ = Once.__qualname__ = f"Once{kind.__name__}"
    return Once


_ONCE = {kind: _once(kind) for kind in ONCE_KINDS}


def option_strings(parser: argparse.ArgumentParser) -> Sequence[str]:
    """Every option string of ``parser`` (for tests)."""
    return [s for a in parser._actions for s in a.option_strings]

"""Screen a new held-out set of cases (``studies/fresh_cases11.txt``) against what the project
already tries: every case the generated matrices make (each argparse option's bad values,
``uss_slam.core.arguments.bad_arguments``; each Hydra schema key's bad values,
``uss_slam.core.schema.cases.bad_values`` as ``tests/test_cli_matrix.py`` collects them; every
path family of ``tests/test_path_families.py`` on every path argument), the hand-written cases
of the test matrices (``tests/test_cli_matrix.py``, ``test_image_families.py``) and the earlier
held-out sets. A new case *repeats* one when it is the same script with

- a generated bad value: the option followed by that value, or ``key=value`` as the schema
  matrix writes it (the override text, compared as typed);
- a path family: its path argument given a path of that family (a missing path, a 300-byte
  name, a link that loops or points nowhere, a file for a folder or the reverse, a path under
  a file: recognised by the names the families make in the case's folder);
- an earlier case: the same setup and the same arguments once the paths are named alike, or
  the same arguments that are not the script's usual base (the same tried input), sent the
  same signal the same way (:func:`delivery`: Ctrl-C to the script alone, to its process
  group, twice; SIGTERM alone or to the group; SIGHUP; Ctrl-Z then ``fg``; or none): a
  SIGTERM to the group where an earlier case pressed Ctrl-C with the same arguments is a new
  case, as is one without a signal where the earlier one sent one.

    python studies/screen_cases.py studies/fresh_cases11.txt   # exit 1 and the repeats, if any

Needs the test folder on ``sys.path`` (it imports the matrices' modules, which import pytest).
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(HERE), str(ROOT / "tests")]

from fresh_cases import MACROS, PSEUDO, SIGNALS, read_cases  # noqa: E402

EARLIER = (
    "fresh_cases.txt",
    "fresh_cases2.txt",
    "fresh_cases3.txt",
    "fresh_cases4.txt",
    "fresh_cases5.txt",
    "fresh_cases6.txt",
    "fresh_cases7.txt",
    "fresh_cases8.txt",
    "fresh_cases9.txt",
    "fresh_cases10.txt",
)
"""The held-out sets so far, in order; a set is screened against those before it."""
ALIASES = {"{tmp}": "{C}", "{m}": "{onnx}", "{out}": "{C}/o", "{s}": "{C}/seq"}
"""The hand-written matrices' path names -> the fresh sets' names."""
FAMILY_PATHS = re.compile(r"\{C\}/(nope|nothing|loop|link|afile|afolder|a/x)\b|a{300}")
"""Paths of tests/test_path_families.py's families, as a case of the fresh sets would write
them (the family's own names; ``{C}/nope`` a missing path)."""


def tokens(prog: str, argv: str) -> tuple[str, ...]:
    """The case's arguments with the macros expanded and the matrices' path names aliased."""
    for name, macro in MACROS.items():
        argv = argv.replace(name, macro)
    for old, new in ALIASES.items():
        argv = argv.replace(old, new)
    try:
        return tuple(shlex.split(argv))
    except ValueError:
        return tuple(argv.split())


def usual(prog: str, cases: list) -> set[str]:
    """Arguments in at least a third of ``prog``'s cases: its base, not what a case tries."""
    mine = [set(tokens(c.prog, c.argv)) for c in cases if c.prog == prog]
    counts: dict[str, int] = {}
    for toks in mine:
        for t in toks:
            counts[t] = counts.get(t, 0) + 1
    return {t for t, n in counts.items() if n * 3 >= len(mine)}


def _tried(toks: tuple[str, ...], base: set[str]) -> tuple[str, ...]:
    """The arguments a case tries: those not of the script's base, each as often as given."""
    return tuple(sorted(t for t in toks if t not in base))


def _environment(case) -> frozenset[str]:
    """The environment variables a case changes (a missing package's ``PYTHONPATH`` aside:
    its setup names the package); the shell's state (``STDOUT=full``, ``closed`` or ``pipe``:
    another state each) with its value."""
    return frozenset(f"{k}={v}" if k in PSEUDO else k for k, v in case.env.items()
                     if k not in ("PYTHONPATH", "PYTHONDONTWRITEBYTECODE"))  # fmt: skip


def delivery(expect: str) -> str | None:
    """How a case sends its signal: the kind of its ``expect`` (``int``, ``gint``, ``int2``,
    ``term``, ``gterm``, ``hup``, ``stop``; the time it is sent after is not compared), None
    for a case that sends none."""
    kind = expect.split(":", 1)[0]
    return kind if kind in SIGNALS else None


def generated_argparse() -> list[tuple[str, tuple[str, ...], str, str]]:
    from test_cli_matrix_arguments import BAD

    return [(prog, b.commands, b.flag, b.value) for prog, b in BAD if b.kind != "undeclared"]


def generated_schema() -> list[tuple[str, str]]:
    from test_cli_matrix import CHECKERS, _override

    found = []
    for prog, make in CHECKERS.items():
        _, _, bad = make()
        found += [(prog, _override(b.key, b.value, b.kind)) for b in bad]
    return found


def handwritten() -> list[tuple[str, tuple[str, ...], str | None]]:
    import test_cli_matrix
    import test_image_families

    cases = [*test_cli_matrix.CASES, *test_cli_matrix.MORE_CASES, *test_image_families.CASES]
    # (a hand-written case's interrupt is a Ctrl-C raised in the script alone)
    return [(c.prog, tokens(c.prog, " ".join(c.argv)), "int" if getattr(c, "interrupt", None)
             else None) for c in cases]  # fmt: skip


def screen(path: Path) -> list[str]:
    """One line per repeat found among ``path``'s cases."""
    new = read_cases(path)
    before = EARLIER[: EARLIER.index(path.name)] if path.name in EARLIER else EARLIER
    earlier = [c for name in before for c in read_cases(HERE / name)]
    found: list[str] = []
    bad_args = generated_argparse()
    bad_keys = generated_schema()
    hand = handwritten()
    for case in new:
        toks = tokens(case.prog, case.argv)
        pairs = set(zip(toks, toks[1:], strict=False))
        for prog, commands, flag, value in bad_args:
            if prog == case.prog and toks[: len(commands)] == commands and (flag, value) in pairs:
                found.append(f"{case.id}: generated argparse case {flag} {value}")
        for prog, override in bad_keys:
            if prog == case.prog and override in toks:
                found.append(f"{case.id}: generated schema case {override}")
        if FAMILY_PATHS.search(case.argv):
            found.append(f"{case.id}: a path family's path")
        base = usual(case.prog, [*earlier, *new])
        tried = _tried(toks, base)
        for old in earlier:
            old_toks = tokens(old.prog, old.argv)
            if old.prog != case.prog:
                continue
            same_setup = set(old.setup) == set(case.setup)
            if delivery(old.expect) != delivery(case.expect):
                continue  # the same arguments, a signal sent otherwise (or none): a new case
            if old_toks == toks and same_setup and old.env == case.env:
                found.append(f"{case.id}: the earlier case {old.id}")
            elif tried and tried == _tried(old_toks, base) and same_setup and old.env == case.env:
                found.append(f"{case.id}: tries what {old.id} tried")
            elif _environment(case) and _environment(case) == _environment(old):
                found.append(f"{case.id}: changes the environment as {old.id} did")
        for prog, hand_toks, sent in hand:
            # (a case with a setup differs by its files, not its arguments: screened by reading)
            if prog != case.prog or sent != delivery(case.expect):
                continue
            if not case.setup and tried and tried == _tried(hand_toks, base):
                found.append(f"{case.id}: a hand-written matrix case ({' '.join(hand_toks)[:80]})")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cases", type=Path)
    args = parser.parse_args(argv)
    found = screen(args.cases)
    n = len(read_cases(args.cases))
    print("\n".join(found) if found else f"{n} cases: no repeat found")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())

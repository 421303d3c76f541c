"""Split the eighth held-out set's outcomes by whether the engineer fixing code was pointed at
the case's family before the set ran.

The set (``studies/fresh_cases8.txt``) was written by one engineer while another fixed code
without reading it. Both were given, by the same lead, lists of families to look for, and the
lists overlapped (argparse abbreviations, odd characters in names, an output folder that is an
input folder, resource limits, the C locale, resolvers, odd image forms, SIGHUP, no CUDA device).
A fix for a family the fixer was pointed at is not a fix the set found held out, so the set's
share is reported twice: over every case, and over the cases outside those families only.

The families below are the ones named to the fixer (as written in its task, before any case
ran); this file was committed before the set's run.

    python studies/fresh_pointed8.py studies/fresh_cases8.txt OUT/results.json
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

# family named to the fixer -> how a case of the set is recognised (its id, env or argv)
POINTED: dict[str, re.Pattern[str]] = {
    "argparse abbreviations of long flags": re.compile(r"-abbrev-"),
    "file names with whitespace (spaces, newlines)": re.compile(r"\{(nl|tab|spend)\}"),
    "the C locale with non-ASCII paths": re.compile(r"LC_ALL=(C|POSIX)"),
    "an output folder that is an input folder, or the same path twice": re.compile(
        r"-out-is-|-same-(sequence|file)-|-target-twice-|-overwrite-an-input-"
    ),
    "resource limits (ulimit)": re.compile(r"ULIMIT_"),
    "Hydra interpolations in overrides": re.compile(r"\$\{\{oc\.|\$\{\{[a-z_.]+\}\}"),
    "odd image forms (palette, 16-bit colour, grey, alpha, odd sizes)": re.compile(
        r"-(grey-alpha|one-bit|two-bit-palette|rgb16)|-odd-size"
    ),
    "SIGHUP / SIGQUIT / SIGPIPE": re.compile(r"\|\s*(hup|quit|pipe):"),
    "no CUDA device": re.compile(r"CUDA_VISIBLE_DEVICES"),
}


def pointed_family(line: str, pointed: dict[str, re.Pattern[str]] = POINTED) -> str | None:
    """The family named to the fixer that a case line of the set belongs to, if any."""
    for family, pattern in pointed.items():
        if pattern.search(line):
            return family
    return None


def split(cases: Path, results: Path, pointed: dict[str, re.Pattern[str]]) -> None:
    """Print the set's shares over every case, the cases in ``pointed``'s families and the rest,
    then every poor or bad case with its family."""
    family = {}
    for line in cases.read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("#"):
            family[line.split("|", 1)[0].strip()] = pointed_family(line, pointed)
    outcomes = json.loads(results.read_text(encoding="utf-8"))["outcomes"]
    for name, keep in (("every case", lambda o: True),
                       ("named to the fixer", lambda o: family.get(o["id"]) is not None),
                       ("not named to the fixer", lambda o: family.get(o["id"]) is None)):  # fmt: skip
        counted = [o for o in outcomes if keep(o) and o["verdict"] != "void"]
        tally = {v: sum(o["verdict"] == v for o in counted) for v in ("good", "poor", "bad")}
        share = 100 * tally["good"] / max(len(counted), 1)
        print(f"{name}: {len(counted)} counted, {tally['good']} good, {tally['poor']} poor, "
              f"{tally['bad']} bad ({share:.1f}% good)")  # fmt: skip
    for o in outcomes:
        if o["verdict"] in ("poor", "bad"):
            print(f"  {o['verdict']:4} {o['id']}: {family.get(o['id']) or 'not named'}")


def split_cli(
    argv: list[str] | None, doc: str, pointed: dict[str, re.Pattern[str]], cases: str
) -> int:
    """The command line of a set's split: ``CASES RESULTS``, then :func:`split`."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("cases", type=Path, help=f"the set, {cases}")
    parser.add_argument("results", type=Path, help="the run's results.json")
    args = parser.parse_args(argv)
    split(args.cases, args.results, pointed)
    return 0


def main(argv: list[str] | None = None) -> int:
    return split_cli(argv, __doc__, POINTED, "studies/fresh_cases8.txt")


if __name__ == "__main__":
    raise SystemExit(main())

"""Split the tenth held-out set's outcomes by whether the engineer fixing code looked at the
case's family before the set ran.

The set (``studies/fresh_cases10.txt``) was written by one engineer while another fixed code
without reading it: the signals left by the ninth set's record (SIGUSR1, SIGUSR2, SIGALRM), the
ninth set's ``uss-eval compare --repeats`` cases, and the families that engineer looked for by
hand, every one listed in the results record ("before the tenth set runs: what was fixed",
landed before the run). A case in one of those families is not one the set found held out, so
the set's share is reported twice: over every case, and over the cases outside those families.

The patterns below were written from that list alone (this file was committed before the set's
run, without reading the set), erring towards counting a case as looked at: every signal with
no meaning of its own however the runner spells it, any ``--repeats`` of uss-eval, every
``-p`` / ``--package`` / ``--resolve`` / ``--cfg`` / ``--info`` (Hydra's switches), a config
group given ``null`` or a number, any ``inf`` or ``nan`` on the command line, any ``${...}``
in an override and any sweep function.

    python studies/fresh_pointed10.py studies/fresh_cases10.txt OUT/results.json
"""

from __future__ import annotations

import re

from fresh_pointed8 import split_cli

GROUPS = (
    r"callbacks|data|experiment|hparams_search|launcher|logger|model(?:/\w+)?|paths|scale"
    r"|segmenter|sequence|slam|system|trainer|validators"
)
"""The config groups of the Hydra apps (``configs/``'s folders)."""

# family the fixer looked at -> how a case of the set is recognised (its id, setup, env or argv)
POINTED: dict[str, re.Pattern[str]] = {
    "SIGUSR1, SIGUSR2, SIGALRM (as SIGTERM)": re.compile(
        r"(?i)\|\s*g?(usr1|usr2|alrm|alarm|sigusr1|sigusr2|sigalrm)\d*:|sigusr|sigalrm"
    ),
    "uss-eval compare --repeats": re.compile(r"\|\s*uss-eval\s*\|.*--repeats"),
    "Hydra's switches (--package without --cfg, --resolve, --cfg, --info)": re.compile(
        r"(?:^|\s|\|)(-p|--package|--resolve|--cfg|--info)(?:\s|=|$)"
    ),
    "a config group given null or a number": re.compile(
        rf"(?:^|[\s|])[+~]*(?:{GROUPS})=(?:null|None|~|[-+]?\d)"
    ),
    "inf or nan as a number": re.compile(r"(?i)(?:=|\s)[-+]?(?:inf|infinity|nan)(?:\s|$|,|\])"),
    "special files as inputs (/dev/null, a FIFO, a folder, binary bytes)": re.compile(
        r"/dev/null|fifo|mkfifo"
    ),
    "HOME unset, TMPDIR missing": re.compile(r"(?<![A-Z_])HOME=(\s|\||$)|TMPDIR="),
    "~key, key=null of a setting": re.compile(r"(?:^|\s)~[a-z_]+(?:\.|\s|$)"),
    "an interpolation in an override": re.compile(r"=[^|\s]*\$\{"),
    "sweeps (range, glob, choice)": re.compile(r"(?:range|glob|choice)\("),
}


def main(argv: list[str] | None = None) -> int:
    return split_cli(argv, __doc__, POINTED, "studies/fresh_cases10.txt")


if __name__ == "__main__":
    raise SystemExit(main())

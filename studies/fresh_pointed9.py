"""Split the ninth held-out set's outcomes by whether the engineer fixing code looked at the
case's family before the set ran.

The set (``studies/fresh_cases9.txt``) was written by one engineer, given no list of families
by anyone, while another fixed code without reading it: five families named by the lead (those
the eighth set's record left) and the families that engineer looked for by hand, every one
listed in the results record ("families looked for by hand before the ninth set", landed before
the run's snapshot). A case in one of those families is not one the set found held out, so the
set's share is reported twice: over every case, and over the cases outside those families.

The patterns below were written from that list and the set's case lines, erring towards
counting a case as looked at (a stdout closed or full beside the stderr closed and the full disk
that were looked at; a new file inside an input folder beside an output that is an input file;
every ``hydra.run.dir`` beside ``out_dir``). One family looked at cannot be split off and
need not be: a refused Hydra run no longer leaves Hydra's log and ``.hydra`` record, which the
run's snapshot of "nothing written" leaves out as it always has. This file was committed before
the set's run.

    python studies/fresh_pointed9.py studies/fresh_cases9.txt OUT/results.json
"""

from __future__ import annotations

import re

from fresh_pointed8 import split_cli

# family the fixer looked at -> how a case of the set is recognised (its id, setup, env or argv)
POINTED: dict[str, re.Pattern[str]] = {
    "hydra.job.chdir": re.compile(r"hydra\.job\.chdir"),
    "an output file that is an input file, or inside an input folder": re.compile(
        r"--out \{C\}/seq/|--plot \{(gt|est)\}"
    ),
    "--plot's formats": re.compile(r"--plot \S+\.(gif|svg|PNG|jpe?g)\b|--plot \{C\}/p\s"),
    "SIGQUIT, SIGXCPU, SIGUSR1/2, SIGALRM, CPU-time limits": re.compile(
        r"\|\s*(quit|xcpu|usr1|usr2|alrm):|ULIMIT_T"
    ),
    "hydra.run.dir beside out_dir; the Hydra log file": re.compile(
        r"hydra\.run\.dir=.*out_dir=|out_dir=.*hydra\.run\.dir=|job_logging"
    ),
    "a multirun's sweep folder": re.compile(r"\|\s*-m |hydra\.mode=MULTIRUN|hydra\.sweep"),
    "label images (the one label reader)": re.compile(r"voc_unpacked"),
    "closed or full standard streams, a full disk": re.compile(r"STDOUT=|STDERR=|DISK_FULL"),
    "TMPDIR, HOME, stdin closed": re.compile(r"TMPDIR=|(?<![A-Z_])HOME=|STDIN="),
    "a trajectory from stdin, CRLF or comma files, unsorted stamps": re.compile(
        r"\bate - |\brpe - |crlf|commas"
    ),
    "--cfg job": re.compile(r"--cfg\b"),
}


def main(argv: list[str] | None = None) -> int:
    return split_cli(argv, __doc__, POINTED, "studies/fresh_cases9.txt")


if __name__ == "__main__":
    raise SystemExit(main())

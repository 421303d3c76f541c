"""Run the held-out cases of ``studies/fresh_cases.txt`` (written down before they were run) as
a new user would: each console script in its own process, in its own folder, with the case's
environment, and classify each one by the contract of ``docs/errors.md``:

- **good**: a bad input is one ``<prog>: error:`` line (argparse: after its usage) holding what
  the case lists, exit code 1 or 2, nothing written into the case's folder and nothing lost; a
  valid input exits 0 (a ``warn`` case with its warning line); Ctrl-C / SIGTERM exit 130 / 143
  with one ``interrupted`` line, the earlier outputs intact and no partial file left;
- **bad**: a traceback, a hang (no exit within the time limit), a process killed by a signal, or
  data lost (a file that was there before changed or gone, the shared inputs changed; a
  successful rerun of a script into its own output folder replaces the files it writes there,
  as docs/errors.md says: for those scripts, :data:`OWN_FOLDERS`, only a file gone is lost);
- **poor**: everything else (more than one line, the line does not name the key / flag / file,
  a wrong exit code, a bad value accepted, a valid input refused, something left behind).

Two kinds of case have a contract of their own: ``pipe`` (stdout a pipe whose reader is gone,
where stdout is the script's product: exit code 1, and nothing on stderr or one line naming
stdout; docs/errors.md, "A closed pipe") and ``jobs`` (a multirun with a failing job: exit
code 1 and an error line naming what the case lists; the other jobs run and write).

A case whose signal came after the script had finished is ``void`` (the timing of the case,
not the script) and left out of the shares.

    nice python studies/fresh_cases.py --world /tmp/fresh/world --work /tmp/fresh/cases \\
        --out outputs/fresh_cases [--cases studies/fresh_cases2.txt] [--only ID-PREFIX] [--jobs 2]

Writes ``OUT/results.json`` (every case: its class, reason, exit code, seconds, stderr tail) and
prints one line per case and the totals.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

from fresh_setups import HIDDEN_OUTPUTS, SETUPS, build_world, snapshot, stop_group
from fresh_setups3 import THIRD
from fresh_setups4 import FOURTH
from fresh_setups5 import FIFTH
from fresh_setups6 import SIXTH
from fresh_setups7 import DEEP_OK, SEVENTH
from fresh_setups8 import EIGHTH, PARTS
from fresh_setups9 import NINTH

from uss_slam.testing.machine import cpu_model

SETUPS.update(THIRD)
SETUPS.update(FOURTH)
SETUPS.update(FIFTH)
SETUPS.update(SIXTH)
SETUPS.update(SEVENTH)
SETUPS.update(EIGHTH)
SETUPS.update(NINTH)

HERE = Path(__file__).resolve().parent
CASES = HERE / "fresh_cases.txt"
BIN = Path(sys.executable).parent
TIMEOUT = 240
TRAIN = (
    "experiment=ci data.source.root={voc} data.target.roots=[{seq}] data.val.roots=[{seq}] "
    "data.val.stride=1 hydra.run.dir={C}/run paths.log_dir={C}/logs logger=none"
)
TRAIN_AT = TRAIN.replace(" hydra.run.dir={C}/run", "")
EXPORT = "ckpt_path={ckpt} out_dir={C}/exports hydra.run.dir={C}/hydra"
MACROS = {"TRAIN_AT": TRAIN_AT, "TRAIN": TRAIN, "EXPORT": EXPORT}


@dataclass(frozen=True)
class Case:
    id: str  # noqa: A003
    prog: str
    expect: str
    setup: tuple[str, ...]
    env: dict[str, str]
    says: tuple[str, ...]
    argv: str


def read_cases(path: Path = CASES) -> list[Case]:
    """The cases of ``fresh_cases.txt`` (its header says the columns)."""
    cases = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        id_, prog, expect, setup, env, says, argv = (c.strip() for c in line.split(" | ", 6))
        envs = dict(e.split("=", 1) for e in env.split(";")) if env != "-" else {}
        cases.append(Case(id_, prog, expect, tuple(s for s in setup.split(",") if s != "-"),
                          envs, tuple(s for s in says.split(",") if s != "-"), argv))  # fmt: skip
    return cases


@dataclass
class Outcome:
    id: str  # noqa: A003
    prog: str
    expect: str
    verdict: str
    reason: str
    code: int | None
    seconds: float
    stderr_tail: str


def _argv(case: Case, paths: dict[str, str]) -> list[str]:
    text = case.argv
    for name, macro in MACROS.items():
        text = text.replace(name, macro)
    return shlex.split(text.format(**paths))


def _without_root_powers() -> list[str]:
    """As root, permissions do not apply: the read-only cases run without that capability."""
    setpriv = shutil.which("setpriv")
    if os.geteuid() != 0 or setpriv is None:
        return []
    return [setpriv, "--bounding-set=-dac_override,-dac_read_search"]


def _run(case: Case, argv: list[str], folder: Path,
         paths: dict[str, str]) -> tuple[int | None, str, float, bool]:  # fmt: skip
    """(exit code or None on a hang, stderr, seconds, whether the signal came after the end)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", COLUMNS="100")
    limits: dict[int, int] = {}
    shell = {k: case.env[k] for k in PSEUDO if k in case.env}  # the shell's state, not variables
    for key, value in case.env.items():
        value = value.format(**paths)
        if key == "PYTHONPATH":  # before the runner's own (a snapshot of the code under test)
            env[key] = os.pathsep.join(p for p in (value, os.environ.get(key, "")) if p)
        elif key in LIMITS:  # ulimit -v / -f (KiB), -n (files)
            limits[LIMITS[key]] = int(value) * (1 if key == "ULIMIT_N" else 1024)
        elif key in PSEUDO:
            continue
        elif value == "":
            env.pop(key, None)
        else:
            env[key] = value

    def preexec() -> None:
        os.setsid()
        # as a terminal's Ctrl-C finds it: a runner started in the background (`cmd &`)
        # ignores SIGINT, and Python then installs no KeyboardInterrupt handler
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)  # a runner under nohup ignores it
        for kind, limit in limits.items():
            resource.setrlimit(kind, (limit, limit))
        if "UMASK" in shell:
            os.umask(int(shell["UMASK"], 8))
        if "CWD_GONE" in shell:  # the working folder deleted (another terminal's `rm -r`)
            os.rmdir(os.getcwd())
        if shell.get("STDOUT") == "closed":
            os.close(1)
        if shell.get("STDIN") == "closed":
            os.close(0)

    powerless = "UMASK" in shell or any(
        s.startswith("ro") or s == "links" or "unreadable" in s for s in case.setup
    )
    prefix = _without_root_powers() if powerless else []
    command = [*prefix, str(BIN / case.prog), *argv]
    cwd = folder
    if "CWD_GONE" in shell:
        cwd = folder / "gone"
        cwd.mkdir()
    stdout = open("/dev/full", "w") if shell.get("STDOUT") == "full" else subprocess.DEVNULL  # noqa: SIM115
    if shell.get("STDOUT") == "pipe":  # a pipe whose reader is gone (`| head -c0`)
        reader, writer = os.pipe()
        os.close(reader)
        stdout = os.fdopen(writer, "w")
    start = time.perf_counter()
    proc = subprocess.Popen(command, cwd=cwd, env=env, stdout=stdout,
                            stderr=subprocess.PIPE, text=True, preexec_fn=preexec)  # fmt: skip
    late = False
    if case.expect.startswith(SIGNALLED):
        kind, delay = case.expect.split(":")
        try:
            proc.wait(timeout=float(delay))
            late = True
        except subprocess.TimeoutExpired:
            _signal(proc, kind)
    try:
        _, err = proc.communicate(timeout=TIMEOUT)
        code: int | None = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate()
        code = None
    if stdout is not subprocess.DEVNULL:
        stdout.close()
    return code, err, time.perf_counter() - start, late


def _signal(proc: subprocess.Popen, kind: str) -> None:
    """Send a case's signal: to the script alone (``int``, ``term``, ``hup``), to its whole
    process group as a terminal does (``gint``: Ctrl-C reaches every process of the foreground
    job, a script's workers included; ``gterm``), Ctrl-C twice 0.5 s apart (``int2``), or
    Ctrl-Z then ``fg`` (``stop``: the group stopped for 3 s, then continued; SIGSTOP, as a
    terminal's SIGTSTP is discarded for a group without a controlling terminal)."""
    try:
        if kind == "stop":
            os.killpg(proc.pid, signal.SIGSTOP)
            time.sleep(3)
            os.killpg(proc.pid, signal.SIGCONT)
        elif kind.startswith("g"):
            os.killpg(proc.pid, SIGNALS[kind])
        else:
            proc.send_signal(SIGNALS[kind])
            if kind == "int2":
                time.sleep(0.5)
                if proc.poll() is None:
                    proc.send_signal(SIGNALS[kind])
    except ProcessLookupError:  # it ended in between
        pass


LIMITS = {"ULIMIT_V": resource.RLIMIT_AS, "ULIMIT_F": resource.RLIMIT_FSIZE,
          "ULIMIT_N": resource.RLIMIT_NOFILE}  # fmt: skip
"""A case's ``env`` keys that set a resource limit of its process (``ulimit -v / -f / -n``)."""
PSEUDO = ("UMASK", "CWD_GONE", "STDOUT", "STDIN")
"""A case's ``env`` keys that set the shell's state: ``UMASK=027``; ``CWD_GONE=1``: the working
folder is deleted as the script starts; ``STDOUT=full`` (``/dev/full``), ``closed`` or ``pipe``
(a pipe whose reading end is closed, as ``| head -c0`` leaves it); ``STDIN=closed`` (``<&-``)."""
SIGNALS = {"int": signal.SIGINT, "term": signal.SIGTERM, "hup": signal.SIGHUP,
           "gint": signal.SIGINT, "gterm": signal.SIGTERM, "int2": signal.SIGINT,
           "stop": signal.SIGSTOP}  # fmt: skip
SIGNALLED = tuple(f"{k}:" for k in SIGNALS)
"""``expect`` of a case that sends a signal after N s: ``int:N`` (Ctrl-C), ``term:N`` (kill),
``hup:N`` (the terminal closed: the same contract as SIGTERM, exit 129), ``gint:N`` /
``gterm:N`` (to the whole process group, as a terminal's Ctrl-C or ``kill -- -PGID``),
``int2:N`` (Ctrl-C pressed twice), ``stop:N`` (Ctrl-Z, then ``fg``: held to ``ok``'s contract)."""
INTERRUPTED = tuple(f"{k}:" for k in SIGNALS if k != "stop")


def classify(case: Case, code: int | None, err: str, before: dict, after: dict,
             paths: dict[str, str]) -> tuple[str, str]:  # fmt: skip
    """(verdict, reason) of one case by the contract (module doc)."""
    lost = [p for p in before if p not in after or after[p] != before[p]]
    new = sorted(p for p in after if p not in before)
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    head = case.prog
    errors = [ln for ln in lines if ln.startswith(head) and ": error: " in ln]
    says = [s.format(**paths) for s in case.says]
    if code is None:
        return "bad", "no exit within the time limit"
    if "Traceback (most recent call last)" in err:
        return "bad", "traceback"
    if code < 0:
        return "bad", f"killed by signal {-code}"
    if case.expect.startswith(INTERRUPTED):
        if lost:
            return "bad", f"earlier output changed or gone: {lost[:2]}"
        want = 128 + SIGNALS[case.expect.split(":")[0]]
        left = [p for p in new if any(h in p for h in HIDDEN_OUTPUTS)]
        if code != want:
            return "poor", f"exit code {code}, expected {want}"
        if not lines or "interrupted" not in lines[-1]:
            return "poor", "no 'interrupted' line at the end"
        if left:
            return "poor", f"left behind: {left[:2]}"
        return "good", ""
    if case.expect.startswith("stop:"):  # stopped and continued: the run goes on as usual
        case = Case(case.id, case.prog, "ok", case.setup, case.env, case.says, case.argv)
    if lost and case.expect in ("ok", "warn") and code == 0 and case.prog in OWN_FOLDERS:
        # a rerun into the script's own output folder replaces the files it writes there
        # (docs/errors.md, "Rerunning into an output"): a file changed is its job, one gone not
        lost = [p for p in lost if p not in after]
    if lost and not (case.expect == "ok" and "--overwrite" in case.argv):  # replacing: its job
        return "bad", f"earlier file changed or gone: {lost[:2]}"
    if case.expect == "pipe":  # stdout a closed pipe where stdout is the product
        if code != 1:
            return "poor", f"exit code {code}, expected 1 (the output was not delivered)"
        others = [ln for ln in lines if ln not in errors]
        if len(errors) > 1 or others:
            return "poor", f"more than one line: {(others or errors)[0][:120]}"
        if errors and "stdout" not in errors[0]:
            return "poor", f"the line does not name stdout: {errors[0][:160]}"
        return "good", ""
    if case.expect == "jobs":  # a multirun with a failing job: the others run, exit code 1
        if code != 1:
            return "poor", f"exit code {code}, expected 1"
        if not any(all(s in e for s in says) for e in errors):
            return "poor", "no error line naming " + ", ".join(says)
        return "good", ""
    if case.expect in ("ok", "warn"):
        if code != 0:
            return (
                "poor",
                f"valid input refused (exit {code}): {(errors or lines or [''])[-1][:160]}",
            )
        warned = [ln for ln in lines if ": warning: " in ln]
        if case.expect == "warn" and not any(all(s in w for s in says) for w in warned):
            return "poor", "no warning naming " + ", ".join(says)
        return "good", ""
    # a bad input
    if code == 0:
        return "poor", "bad input accepted (exit 0)"
    if code not in (1, 2):
        return "poor", f"exit code {code}"
    if len(errors) != 1:
        return "poor", f"{len(errors)} error lines of {len(lines)} lines"
    others = [ln for ln in lines if ln not in errors and not ln.startswith(("usage:", " "))
              and ": warning: " not in ln]  # fmt: skip
    if others:
        return "poor", f"more than the error line: {others[0][:120]}"
    missing = [s for s in says if s not in errors[0]]
    if missing:
        return "poor", f"the line does not name {missing}: {errors[0][:200]}"
    if new:
        return "poor", f"written on a failed run: {new[:2]}"
    return "good", ""


OWN_FOLDERS = ("uss-eval", "uss-demo", "uss-slam", "uss-train", "uss-export", "uss-experiments")
"""Scripts whose output is a folder of their own: a successful rerun into it replaces the files
it writes there, without a flag (``uss-synth`` and ``uss-vocab build`` need ``--overwrite``)."""

LONG = {
    "u128": "é" * 128,  # 128 characters, 256 bytes: one byte over the file system's limit
    "deep": "/".join(["d" * 200] * 21),  # 21 names of 200 bytes: over PATH_MAX (4096)
    "deep_ok": DEEP_OK,  # 14 names of 200 bytes: long, but under PATH_MAX
    **PARTS,  # the eighth set's: names with a newline, `%`, `$`, a quote, ...; a long number
}
"""Path parts the cases' templates may name besides the world's."""


TUM = Path(os.environ.get("USS_FRESH_TUM",
                         "/work/shared/data/tum/rgbd_dataset_freiburg1_rpy_frames401-523"))  # fmt: skip
"""A real TUM RGB-D sequence (``{tum}``: rgb/, depth/, no labels, no intrinsics.yaml), read only;
``{R}`` is the code's own folder (its ``configs/``)."""


def run_case(case: Case, world: dict[str, str], work: Path) -> Outcome:
    folder = work / case.id
    if folder.exists():
        for p in folder.rglob("*"):
            if p.is_dir() and not p.is_symlink():
                p.chmod(0o755)
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    paths = {**world, "C": str(folder), "R": str(HERE.parent), "tum": str(TUM), **LONG}
    started = [SETUPS[name](folder, world) for name in case.setup]
    busy = [p for p in started if isinstance(p, subprocess.Popen)]
    before = snapshot(folder)
    world_before = snapshot(Path(world["W"]), quick=True)
    code, err, seconds, late = _run(case, _argv(case, paths), folder, paths)
    after = snapshot(folder)
    if busy:  # the other writer's own staging, temporary and lock files are its business
        for proc in busy:
            stop_group(proc)
        before, after = ({p: v for p, v in files.items() if not any(h in p for h in HIDDEN_OUTPUTS)}
                         for files in (before, after))  # fmt: skip
    if snapshot(Path(world["W"]), quick=True) != world_before:
        verdict, reason = "bad", "the shared inputs changed"
    elif late:
        verdict, reason = "void", "finished before the signal"
    else:
        verdict, reason = classify(case, code, err, before, after, paths)
    tail = "\n".join(err.strip().splitlines()[-6:])
    return Outcome(case.id, case.prog, case.expect, verdict, reason, code, round(seconds, 1), tail)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--world", type=Path, default=Path("/tmp/fresh/world"))
    parser.add_argument("--work", type=Path, default=Path("/tmp/fresh/cases"))
    parser.add_argument("--out", type=Path, default=Path("outputs/fresh_cases"))
    parser.add_argument(
        "--only", default="", help="comma-separated id prefixes of the cases to run"
    )
    parser.add_argument("--merge", type=Path, default=None,
                        help="an earlier results.json: its outcomes of the cases not run now are kept")  # fmt: skip
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--cases", type=Path, default=CASES,
                        help="the case list (default: studies/fresh_cases.txt)")  # fmt: skip
    args = parser.parse_args(argv)
    prefixes = tuple(args.only.split(",")) if args.only else ("",)
    cases = [c for c in read_cases(args.cases) if c.id.startswith(prefixes)]
    world = build_world(args.world.resolve(), BIN)
    args.work.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with ThreadPoolExecutor(args.jobs) as pool:
        outcomes = []
        for out in pool.map(lambda c: run_case(c, world, args.work.resolve()), cases):
            outcomes.append(out)
            print(f"{out.verdict:5} {out.id:45} exit {out.code} {out.seconds:6.1f} s  "
                  f"{out.reason[:150]}", flush=True)  # fmt: skip
    if args.merge is not None:
        ran = {o.id for o in outcomes}
        earlier = [Outcome(**o) for o in json.loads(args.merge.read_text())["outcomes"]]
        order = {c.id: i for i, c in enumerate(read_cases(args.cases))}
        outcomes = sorted([*outcomes, *(o for o in earlier if o.id not in ran)],
                          key=lambda o: order.get(o.id, len(order)))  # fmt: skip
    counted = [o for o in outcomes if o.verdict != "void"]
    totals = {v: sum(o.verdict == v for o in counted) for v in ("good", "poor", "bad")}
    share = totals["good"] / max(len(counted), 1)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps({
        "cases": len(outcomes), "void": len(outcomes) - len(counted), **totals,
        "good_share": round(share, 4), "seconds": round(time.perf_counter() - start),
        "cpu": cpu_model(), "load_before": os.getloadavg()[0],
        "outcomes": [asdict(o) for o in outcomes]}, indent=1) + "\n")  # fmt: skip
    print(f"{len(counted)} cases ({len(outcomes) - len(counted)} void): {totals['good']} good, "
          f"{totals['poor']} poor, {totals['bad']} bad ({100 * share:.1f}% good); "
          f"{time.perf_counter() - start:.0f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

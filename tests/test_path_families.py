"""Every path family for every path argument of every console script (the "one path layer").

A path argument is an input file, an input folder, an output file or an output folder of one
console script (:data:`PATH_ARGS`); a family is a kind of bad path a user gives
(:data:`FAMILIES`): a missing one, a name longer than the file system allows (300 bytes), a
symbolic link that loops, one that points nowhere, a file where a folder is expected and a
folder where a file is, a parent that is a file. Each (argument, family) pair is one case,
held to the error contract of ``docs/errors.md``: exit code 1, one stderr line
``<prog>: error: <key>=<path>: ...`` (positional inputs: ``<path>: ...``) naming the argument,
no traceback, and nothing written under the case's folder.

The cases run in this process (as ``tests/test_cli_matrix.py`` runs its cases). Those of the
slow scripts (``uss-train``: it builds its data module first) are marked ``slow``. A new path
argument is one row of :data:`PATH_ARGS`; every family applies to it by its kind.
"""

# ruff: noqa: F811  (world: the shared fixture, imported, then a parameter of the tests)

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from test_cli_matrix import (  # noqa: F401  (world: the fixture of the shared inputs)
    EXPERIMENTS,
    EXPORT,
    SLAM,
    TRAIN,
    colour_onnx,
    run_console_script,
    snapshot,
    world,
)

IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER = (
    "input file",
    "input folder",
    "output file",
    "output folder",
)


@dataclass(frozen=True)
class PathArg:
    """One path argument: ``argv`` is a template whose ``{P}`` is the path under test (the other
    fields as in ``tests/test_cli_matrix.py``: ``{tmp}``, ``{seq}``, ``{m}`` a colour model);
    ``key`` how the error line names it (None: a positional argument, named by its path)."""

    prog: str
    key: str | None
    kind: str
    argv: str
    slow: bool = False
    name: str | None = None
    """The id's name of the argument (default: its key, or the subcommand of a positional)."""

    @property
    def id(self) -> str:
        if self.name is not None:
            return f"{self.prog.removeprefix('uss-')}-{self.name}"
        first = self.argv.split()[0]  # a positional argument: by its subcommand
        name = (self.key or ("model" if first == "{P}" else first)).strip("-").replace(".", "-")
        return f"{self.prog.removeprefix('uss-')}-{name}"


TRAIN_BASE = TRAIN.replace("hydra.run.dir={tmp}/run", "").replace("data.source.root={voc}", "")
PATH_ARGS = [
    PathArg("uss-synth", "--out", OUT_FOLDER, "voc --images 1 --size 32x24 --out {P} --quiet"),
    PathArg("uss-synth", "--out", OUT_FOLDER,
            "sequence --preset static_xyz --frames 2 --size 32x24 --out {P} --quiet",
            name="sequence-out"),
    PathArg("uss-traj", None, IN_FILE, "ate {P} {gt}"),
    PathArg("uss-traj", None, IN_FILE, "rpe {gt} {P}"),
    PathArg("uss-traj", "--plot", OUT_FILE, "ate {gt} {gt} --plot {P}"),
    PathArg("uss-vocab", None, IN_FOLDER, "build {P} --out {tmp}/v.txt -k 3 -L 2"),
    PathArg("uss-vocab", "--out", OUT_FILE, "build {seq} --out {P} -k 3 -L 2"),
    PathArg("uss-vocab", None, IN_FILE, "info {P}"),
    PathArg("uss-eval", None, IN_FILE, "{P} --sequence {seq} --out {tmp}/eval"),
    PathArg("uss-eval", "--sequence", IN_FOLDER, "{m} --sequence {P} --out {tmp}/eval"),
    PathArg("uss-eval", "--out", OUT_FOLDER, "{m} --sequence {seq} --out {P}"),
    # (the values of data.val are checked first; its reader then names a bad folder by its path)
    PathArg("uss-eval", None, IN_FOLDER, "{m} data.val.roots=[{P}] --out {tmp}/eval",
            name="data-val-roots"),
    PathArg("uss-eval", None, IN_FILE, "compare {P} {m} --sequence {seq} --out {tmp}/cmp",
            name="compare-model"),
    PathArg("uss-eval", "--sequence", IN_FOLDER, "compare {m} {m} --sequence {P} --out {tmp}/cmp",
            name="compare-sequence"),
    PathArg("uss-eval", "--labels", IN_FOLDER,
            "compare {m} {m} --sequence {seq} --labels {P} --out {tmp}/cmp", name="compare-labels"),
    PathArg("uss-eval", "--source", IN_FOLDER,
            "compare {m} {m} --sequence {seq} --source {P} --out {tmp}/cmp", name="compare-source"),
    PathArg("uss-eval", "--out", OUT_FOLDER, "compare {m} {m} --sequence {seq} --out {P}",
            name="compare-out"),
    PathArg("uss-demo", "--out", OUT_FOLDER, "--out {P} --experiment ci --until data --quiet"),
    PathArg("uss-demo", "--sequence", IN_FOLDER,
            "--out {tmp}/demo --experiment ci --until data --sequence {P} --quiet"),
    PathArg("uss-slam", "sequence.path", IN_FOLDER,
            "sequence.path={P} out_dir={tmp}/out progress=false"),
    PathArg("uss-slam", "out_dir", OUT_FOLDER,
            "sequence.path={seq} out_dir={P} progress=false"),
    PathArg("uss-slam", "segmenter.path", IN_FILE,
            "sequence.path={seq} out_dir={tmp}/out progress=false segmenter=onnx "
            "segmenter.path={P}"),
    # (one epoch of experiment=ci's two: the cases that train only need the run folder written)
    PathArg("uss-train", "hydra.run.dir", OUT_FOLDER,
            f"{TRAIN_BASE} data.source.root={{voc}} hydra.run.dir={{P}} model.max_iters=2",
            slow=True),
    PathArg("uss-train", "data.source.root", IN_FOLDER,
            f"{TRAIN_BASE} data.source.root={{P}} hydra.run.dir={{tmp}}/run", slow=True),
    PathArg("uss-train", "ckpt_path", IN_FILE,
            f"{TRAIN_BASE} data.source.root={{voc}} hydra.run.dir={{tmp}}/run ckpt_path={{P}}",
            slow=True),
    PathArg("uss-export", "ckpt_path", IN_FILE, "ckpt_path={P} hydra.run.dir={tmp}/hydra"),
    PathArg("uss-export", "out_dir", OUT_FOLDER, EXPORT.replace("{tmp}/exports", "{P}")),
    PathArg("uss-export", "hydra.run.dir", OUT_FOLDER,
            EXPORT.replace("hydra.run.dir={tmp}/hydra", "hydra.run.dir={P}")),
    PathArg("uss-export", "calibration.root", IN_FOLDER,
            f"{EXPORT} int8=true calibration.root={{P}}"),
    PathArg("uss-experiments", "out_dir", OUT_FOLDER, "out_dir={P} dry_run=true"),
    PathArg("uss-experiments", "data.real.tum", IN_FOLDER,
            f"{EXPERIMENTS} data.kind=real data.real.voc={{tmp}} data.real.sbd={{tmp}} "
            "data.real.coco={tmp} data.real.tum={P} data.real.target=[walking_xyz] init.kind=scratch "
            "sequences=[walking_xyz]"),
    PathArg("uss-experiments", "init.path", IN_FILE,
            f"{EXPERIMENTS} init.kind=pretrained init.path={{P}}"),
]  # fmt: skip


# ------------------------------------------------------------------------------ families
# A family makes the bad path in the case's folder ``tmp`` and returns it with the words its
# error line must hold besides the argument's name (``{P}``: the path).

Family = Callable[[Path, str], tuple[Path, tuple[str, ...]]]


def missing(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    return tmp / "nothing", ("does not exist",)


def long_name(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    return tmp / ("a" * 300), ("is 300 bytes; expected at most 255",)


def symlink_loop(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    (tmp / "loop").symlink_to(tmp / "loop")
    return tmp / "loop", ("a symbolic link that loops",)


def loop_on_the_way(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    (tmp / "a").symlink_to(tmp / "b")
    (tmp / "b").symlink_to(tmp / "a")
    return tmp / "a" / "x", ("a symbolic link that loops",)


def dangling(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    (tmp / "link").symlink_to(tmp / "gone")
    return tmp / "link", ("a symbolic link to", "which does not exist")


def a_file(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    (tmp / "afile").write_text("a file\n")
    return tmp / "afile", ("is a file; expected a folder",)


def a_folder(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    (tmp / "afolder").mkdir()
    (tmp / "afolder" / "inside.txt").write_text("the user's file\n")
    return tmp / "afolder", ("is a folder; expected a file",)


def under_a_file(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    (tmp / "afile").write_text("a file\n")
    return tmp / "afile" / "x", (f"{tmp / 'afile'} is a file",)


def not_utf8(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    """A name with a Latin-1 byte (a disk from another system): the reports and JSON files
    that hold the path could not be written (a UnicodeEncodeError traceback after the work)."""
    folder = tmp / os.fsdecode(b"caf\xe9")
    folder.mkdir()
    return folder / "x", ("the path holds a byte that is not UTF-8 (0xe9",)


def home_folder(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    """``--out=~/x`` (bash expands ``~`` only at a word's start or after ``name=``; ``sh`` and a
    quoted value never): expanded by the script as a shell would, for every path argument. The
    case's ``HOME`` is a folder of its own, ``~/afile/x`` fails there as ``afile`` is a file
    (a folder named ``~`` would have been made in the working folder)."""
    home = Path(os.environ["HOME"])  # the test's: a folder beside the case's
    (home / "afile").write_text("a file\n")
    return Path("~") / "afile" / "x", (f"{home / 'afile'} is a file",)


def unknown_user(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    """``~nosuchuser/x``: a shell leaves it as it is, and so do the scripts: refused, not made
    into a folder named ``~nosuchuser``."""
    return Path("~nosuchuser-uss") / "x", (
        "starts with '~",
        "this system has no user 'nosuchuser-uss'",
    )


def trailing_slash(tmp: Path, kind: str) -> tuple[Path, tuple[str, ...]]:
    """``--out DIR/v.txt/``: a final ``/`` names a folder (the file ``v.txt`` was written)."""
    return f"{tmp / 'v.txt'}/", ("ends with '/', which names a folder",)  # type: ignore[return-value]


FAMILIES: dict[str, tuple[Family, tuple[str, ...]]] = {
    "missing": (missing, (IN_FILE, IN_FOLDER)),
    "name-300-bytes": (long_name, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "symlink-loop": (symlink_loop, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "loop-on-the-way": (loop_on_the_way, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "dangling-link": (dangling, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "file-for-a-folder": (a_file, (IN_FOLDER, OUT_FOLDER)),
    "folder-for-a-file": (a_folder, (IN_FILE, OUT_FILE)),
    "under-a-file": (under_a_file, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "not-utf-8": (not_utf8, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "home-folder": (home_folder, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "unknown-user": (unknown_user, (IN_FILE, IN_FOLDER, OUT_FILE, OUT_FOLDER)),
    "trailing-slash": (trailing_slash, (OUT_FILE,)),
}
"""Family name -> (how to make it, the kinds of argument it applies to)."""


def shown(text: str) -> str:
    """``text`` as a line shows it: a byte that is not UTF-8 escaped (``\\udce9``)."""
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _cases() -> list:
    params = []
    for arg in PATH_ARGS:
        for name, (_, kinds) in FAMILIES.items():
            if arg.kind in kinds:
                marks = (pytest.mark.slow,) if arg.slow else ()
                params.append(pytest.param(arg, name, id=f"{arg.id}-{name}", marks=marks))
    return params


def _run(prog: str, argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys) -> tuple[int, str]:
    """``prog argv`` in this process (exit code, stderr), Hydra's global state cleared after it
    and logging's own tracebacks off (a handler writing to a refused path)."""
    monkeypatch.setattr(logging, "raiseExceptions", False)
    try:
        code, _, err = run_console_script(prog, argv, monkeypatch, capsys)
    finally:
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    return code, err


def _with_models(arg: PathArg, paths: dict, tmp_path: Path) -> PathArg:
    """``arg`` with its ``{m}`` models written into ``paths`` (``uss-eval compare``: two models
    whose labels differ, so the comparison runs)."""
    if "{m}" not in arg.argv:
        return arg
    paths["m"] = tmp_path / "m.onnx"
    paths["m"].write_bytes(colour_onnx({"tmp": tmp_path}))
    if arg.argv.count("{m}") != 2:
        return arg
    from shared_helpers import colour_model, segmenter_props

    from uss_slam.core.classes import CLASS_NAMES

    paths["m2"] = colour_model(tmp_path / "m2.onnx", segmenter_props(CLASS_NAMES), bias=100.0)
    return dataclasses.replace(arg, argv=arg.argv.replace("{m} {m}", "{m} {m2}"))


@pytest.mark.parametrize(("arg", "family"), _cases())
def test_path_family(
    arg: PathArg,
    family: str,
    world: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    """One line naming the argument and the path, exit code 1, nothing written."""
    home = tmp_path.parent / f"{tmp_path.name}-home"  # (onnxruntime writes into ~/.cache)
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    make, _ = FAMILIES[family]
    bad, says = make(tmp_path, arg.kind)
    paths = {**world, "tmp": tmp_path, "P": bad}
    if "{m}" in arg.argv:
        paths["m"] = tmp_path / "m.onnx"
        paths["m"].write_bytes(colour_onnx({"tmp": tmp_path}))
        if arg.argv.count("{m}") == 2:  # uss-eval compare: two models, not one given twice
            paths["m2"] = tmp_path / "m2.onnx"
            paths["m2"].write_bytes(colour_onnx({"tmp": tmp_path}) + b"\n")
            arg = dataclasses.replace(arg, argv=arg.argv.replace("{m} {m}", "{m} {m2}"))
    template = arg.argv
    if family in ("not-utf-8", "home-folder", "unknown-user"):  # Hydra reads these quoted
        template = template.replace("={P}", "='{P}'").replace("=[{P}]", "=['{P}']")
    argv = [a.format(**paths) for a in template.split()]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(logging, "raiseExceptions", False)
    for stream in (sys.stdout, sys.stderr):  # as the console scripts' launcher sets them
        stream.reconfigure(errors="backslashreplace")
    before = snapshot(tmp_path)
    links = sorted(p for p in tmp_path.rglob("*") if p.is_symlink())
    code, err = _run(arg.prog, argv, monkeypatch, capsys)
    lines = err.strip().splitlines()
    assert "Traceback" not in err, err
    assert code == 1 and len(lines) == 1, err
    given = os.path.expanduser(bad)  # (``~/x``: the scripts expand it as a shell would)
    named = shown(given if arg.key is None else f"{arg.key}={given}")
    assert lines[0].startswith(f"{arg.prog}: error: ") or (
        lines[0].startswith(f"{arg.prog} {arg.argv.split()[0]}: error: ")  # a subcommand's
    ), err
    assert named in lines[0], (named, lines[0])
    for text in says:
        assert text.format(P=bad) in lines[0], (text, lines[0])
    assert snapshot(tmp_path) == before
    assert sorted(p for p in tmp_path.rglob("*") if p.is_symlink()) == links  # none replaced
    assert all(os.path.lexists(p) for p in links)


def test_export_name_too_long(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``uss-export name=<300 bytes>``: the model's file name is one line naming ``name``."""
    name = "a" * 300
    argv = [a.format(**world, tmp=tmp_path) for a in EXPORT.split()] + [f"name={name}"]
    monkeypatch.chdir(tmp_path)
    code, err = _run("uss-export", argv, monkeypatch, capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"uss-export: error: name={tmp_path}/exports/{name}.onnx: the name "), err
    assert "is 305 bytes; expected at most 255" in err
    assert not (tmp_path / "exports").exists()


# ------------------------------------------------------------------------------ read-only


def _without_root_powers() -> list[str]:
    """A command prefix under which permissions apply: root overrides them (its
    ``CAP_DAC_OVERRIDE``), so as root the script runs without that capability."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("root without setpriv: a read-only folder is writable")
    return [setpriv, "--bounding-set=-dac_override,-dac_read_search"]


LAUNCH = (
    "import sys; from uss_slam.core.launch import launch; sys.argv = sys.argv[1:]; "
    "sys.exit(launch(sys.argv[0]))"
)
"""``python -c LAUNCH <prog> ARGS``: the console script, as its entry point runs it."""


@pytest.mark.parametrize(
    "arg",
    [pytest.param(a, id=a.id, marks=() if a.prog == "uss-slam" else (pytest.mark.slow,))
     for a in PATH_ARGS if a.kind in (OUT_FILE, OUT_FOLDER)],
)  # fmt: skip
def test_read_only_output_location(arg: PathArg, world: dict[str, Path], tmp_path: Path) -> None:
    """An output in a read-only folder (an existing read-only output folder, or a new file in
    one) is one line naming the argument, before any work: for the Hydra apps before Hydra
    opens its log file there (it raised a 56-line traceback in uss-slam)."""
    locked = tmp_path / "ro"
    locked.mkdir()
    bad = locked if arg.kind == OUT_FOLDER else locked / "out.png"
    paths = {**world, "tmp": tmp_path, "P": bad}
    if "{m}" in arg.argv:
        paths["m"] = tmp_path / "m.onnx"
        paths["m"].write_bytes(colour_onnx({"tmp": tmp_path}))
    argv = [a.format(**paths) for a in arg.argv.split()]
    locked.chmod(0o555)
    try:
        done = subprocess.run(
            [*_without_root_powers(), sys.executable, "-c", LAUNCH, arg.prog, *argv],
            cwd=tmp_path, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    finally:
        locked.chmod(0o755)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, done.stderr
    named = str(bad) if arg.key is None else f"{arg.key}={bad}"
    head = arg.prog + (" compare" if arg.argv.startswith("compare ") else "")
    assert lines[0].startswith(f"{head}: error: {named}: "), lines[0]
    assert f"cannot write to {locked} (Permission denied)" in lines[0], lines[0]
    assert not any(locked.iterdir())


# ------------------------------------------------------------------------------ odd but valid


def _accepted(arg: PathArg) -> list:
    """The case of ``arg``: marked ``slow`` where the script's run takes seconds (training,
    an export, the demo's data stage, the experiments' plan)."""
    heavy = arg.slow or arg.prog in ("uss-export", "uss-demo", "uss-experiments")
    return [pytest.param(arg, id=arg.id, marks=(pytest.mark.slow,) if heavy else ())]


@pytest.mark.parametrize(
    "arg", [p for a in PATH_ARGS if a.kind in (OUT_FILE, OUT_FOLDER) for p in _accepted(a)]
)
def test_an_odd_but_valid_output_path_is_taken(
    arg: PathArg, world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """An output given relative to the working folder through ``..``, with a space and a
    non-ASCII name (``../out dir/ré/x``, quoted for Hydra as its values need): the script runs
    and writes there (``..`` spelled in the path named the output's lock apart from the
    script's own, and ``uss-slam`` found its own run folder "in use by" itself)."""
    work = tmp_path / "work"
    work.mkdir()
    name = {OUT_FILE: "x.png" if arg.prog == "uss-traj" else "x.txt"}.get(arg.kind, "x")
    odd = f"../out dir/ré/{name}"
    paths = {**world, "tmp": tmp_path, "P": odd}
    arg = _with_models(arg, paths, tmp_path)
    template = arg.argv.replace("={P}", "='{P}'")  # a Hydra value with a space: quoted
    argv = [a.format(**paths) for a in template.split()]
    monkeypatch.chdir(work)
    code, err = _run(arg.prog, argv, monkeypatch, capsys)
    assert code == 0, err
    assert (tmp_path / "out dir" / "ré" / name).exists(), err


@pytest.mark.parametrize(
    "arg",
    [pytest.param(a, id=a.id, marks=(pytest.mark.slow,) if a.slow else ())
     for a in PATH_ARGS if a.kind in (OUT_FILE, OUT_FOLDER)],
)  # fmt: skip
def test_an_empty_output_path_is_refused(
    arg: PathArg, world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``out_dir=`` (or ``--out ''``): ``Path('')`` is the working folder, into which
    ``uss-slam`` wrote its run. One line naming the argument (argparse: after its usage, exit
    code 2), nothing written into the working folder."""
    paths = {**world, "tmp": tmp_path, "P": ""}
    if "{m}" in arg.argv:
        paths["m"] = tmp_path / "m.onnx"
        paths["m"].write_bytes(colour_onnx({"tmp": tmp_path}))
        if arg.argv.count("{m}") == 2:
            arg = dataclasses.replace(arg, argv=arg.argv.replace("{m} {m}", "{m} {gt}"))
    argv = [a.format(**paths) for a in arg.argv.split()]
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    code, err = _run(arg.prog, argv, monkeypatch, capsys)
    lines = err.strip().splitlines()
    assert "Traceback" not in err, err
    assert code in (1, 2) and all(line.startswith(("usage:", " ")) for line in lines[:-1]), err
    assert f"{arg.key}=" in lines[-1] or f"argument {arg.key}" in lines[-1], err
    assert list(work.iterdir()) == []


@pytest.mark.parametrize(
    "arg", [p for a in PATH_ARGS if a.kind == OUT_FOLDER for p in _accepted(a)]
)
def test_an_output_folder_given_as_a_link_is_written_through(
    arg: PathArg, world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """An output folder named by a link to an empty folder (``--out run -> /big/disk/run``):
    the outputs go where it points and the link stays (``uss-synth`` replaced the link by a
    folder, left ``.<name>.partial-*-old`` beside it and a marker in the folder it pointed to)."""
    target = tmp_path / "disk" / "run"
    target.mkdir(parents=True)
    (tmp_path / "link").symlink_to(target)
    paths = {**world, "tmp": tmp_path, "P": tmp_path / "link"}
    arg = _with_models(arg, paths, tmp_path)
    argv = [a.format(**paths) for a in arg.argv.split()]
    monkeypatch.chdir(tmp_path)
    code, err = _run(arg.prog, argv, monkeypatch, capsys)
    assert code == 0, err
    assert (tmp_path / "link").is_symlink() and any(target.iterdir())
    hidden = [p.name for p in tmp_path.iterdir() if p.name.startswith(".link")]
    assert hidden == [], hidden

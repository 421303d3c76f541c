"""studies/fresh_cases.py's classification of a case by docs/errors.md: a successful rerun into
a script's own output folder replaces the files it writes there (not data lost), a file gone
or a file changed by a failed run or by an output-file script without --overwrite is."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

STUDIES = Path(__file__).resolve().parents[2] / "studies"


def _case(fresh, prog: str, expect: str, argv: str = "--out {C}/e"):
    return fresh.Case("c", prog, expect, (), {}, (), argv)


@pytest.mark.parametrize(
    ("prog", "expect", "code", "after", "verdict"),
    [
        ("uss-eval", "ok", 0, {"e/eval.md": "new", "e/eval.json": "new"}, "good"),  # rerun
        ("uss-eval", "ok", 0, {"e/eval.json": "new"}, "bad"),  # its eval.md gone
        ("uss-eval", "error", 1, {"e/eval.md": "new"}, "bad"),  # a failed run changed it
        ("uss-vocab", "ok", 0, {"e/eval.md": "new"}, "bad"),  # a file output: --overwrite
    ],
)
def test_rerun_into_own_folder(fresh, prog, expect, code, after, verdict) -> None:
    before = {"e/eval.md": "old"}
    err = "" if code == 0 else f"{prog}: error: --out: bad"
    got, _ = fresh.classify(_case(fresh, prog, expect), code, err, before, after, {})
    assert got == verdict


def test_the_screen_flags_a_generated_case_and_an_earlier_one(fresh, tmp_path) -> None:
    """studies/screen_cases.py: a case that is a generated argparse value (``--images 0``), one
    that repeats an earlier set's case and a new one; only the first two are repeats."""
    import screen_cases

    cases = tmp_path / "cases.txt"
    cases.write_text(
        "a | uss-synth | error | - | - | --images | voc --images 0 --size 48x32 --out {C}/v --quiet\n"
        "b | uss-traj | ok | - | - | - | ate {gt} {est} --align SE3\n"
        "c | uss-traj | ok | - | - | - | ate {est} {gt} --align none --bands 0.125\n"
    )
    found = screen_cases.screen(cases)
    assert any(f.startswith("a: generated argparse case --images 0") for f in found), found
    assert any(f.startswith("b: ") for f in found), found
    assert not any(f.startswith("c: ") for f in found), found


def test_the_screen_compares_how_a_signal_is_sent(fresh, tmp_path, monkeypatch) -> None:
    """The same arguments are a repeat only when the signal is sent the same way: Ctrl-C to
    the script where an earlier case pressed it (at another time) is one; SIGTERM to the
    process group, Ctrl-C twice and no signal at all are new cases."""
    import screen_cases

    argv = "sequence.path={seq} out_dir={C}/o slam.workers=3 segmenter=labels"
    (tmp_path / "old.txt").write_text(f"o | uss-slam | int:4 | - | - | - | {argv}\n")
    cases = tmp_path / "cases.txt"
    cases.write_text(
        f"a | uss-slam | int:9 | - | - | - | {argv}\n"
        f"b | uss-slam | gterm:4 | - | - | - | {argv}\n"
        f"c | uss-slam | int2:4 | - | - | - | {argv}\n"
        f"d | uss-slam | ok | - | - | - | {argv}\n"
    )
    monkeypatch.setattr(screen_cases, "HERE", tmp_path)
    monkeypatch.setattr(screen_cases, "EARLIER", ("old.txt",))
    found = screen_cases.screen(cases)
    assert [f for f in found if f.startswith("a: ")] == ["a: the earlier case o"], found
    assert not any(f.startswith(("b: ", "c: ", "d: ")) for f in found), found


@pytest.mark.parametrize(
    ("code", "err", "verdict"),
    [
        (129, "uss-slam: interrupted (SIGHUP)", "good"),
        (-1, "", "bad"),  # killed by the hang-up: the default action
        (143, "uss-slam: interrupted (SIGTERM)", "poor"),  # another signal's exit code
    ],
)
def test_a_hang_up_case_is_held_to_sigterms_contract(fresh, code, err, verdict) -> None:
    """``hup:N`` (the terminal closed) expects 128 + 1 and the one ``interrupted`` line."""
    case = _case(fresh, "uss-slam", "hup:4", "out_dir={C}/o")
    assert fresh.classify(case, code, err, {}, {}, {})[0] == verdict


def _probe(fresh, case, probe: str, tmp_path) -> tuple[int, str]:
    """Run ``case`` with Python as its script (``python -c probe``): its exit code and stderr."""
    saved = fresh.BIN
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "uss-traj").symlink_to(sys.executable)
    fresh.BIN = tmp_path / "bin"
    try:
        code, err, _, _ = fresh._run(case, ["-c", probe], tmp_path, {})
    finally:
        fresh.BIN = saved
    return code, err


def test_the_shell_state_of_a_case_reaches_its_process(fresh, tmp_path) -> None:
    """``UMASK``, ``CWD_GONE`` and ``ULIMIT_N`` set the child's state, not its environment."""
    case = fresh.Case("c", "uss-traj", "ok", (), {"UMASK": "077", "CWD_GONE": "1",
                                                  "ULIMIT_N": "50"}, (), "")  # fmt: skip
    probe = (
        "import os, resource, sys\n"
        "try:\n    os.getcwd(); gone = False\nexcept FileNotFoundError:\n    gone = True\n"
        "ok = os.umask(0) == 0o77 and resource.getrlimit(resource.RLIMIT_NOFILE)[0] == 50\n"
        "sys.exit(0 if ok and gone and 'UMASK' not in os.environ else 3)"
    )
    code, err = _probe(fresh, case, probe, tmp_path)
    assert code == 0, err
    assert not (tmp_path / "gone").exists()


def test_stop_group_signals_then_kills_what_ignores_it(fresh) -> None:
    import signal
    import subprocess

    from fresh_setups import stop_group

    sleeper = subprocess.Popen(["sleep", "30"], start_new_session=True)
    stop_group(sleeper, grace=5)
    assert sleeper.returncode == -signal.SIGTERM
    ignoring = [sys.executable, "-c", "import signal, time; "
                "signal.signal(signal.SIGINT, signal.SIG_IGN); print(flush=True); time.sleep(30)"]  # fmt: skip
    deaf = subprocess.Popen(ignoring, start_new_session=True, stdout=subprocess.PIPE)
    deaf.stdout.readline()  # its handler is set
    stop_group(deaf, signal.SIGINT, grace=0.5)
    assert deaf.returncode == -signal.SIGKILL
    stop_group(deaf)  # an ended one: nothing to do
    deaf.stdout.close()


def test_a_stopped_and_continued_case_is_held_to_oks_contract(fresh) -> None:
    """``stop:N`` (Ctrl-Z, then ``fg``): the run must end as a valid input does."""
    case = fresh.Case("c", "uss-slam", "stop:3", (), {}, (), "out_dir={C}/o")
    assert fresh.classify(case, 0, "", {}, {"o/run.json": "x"}, {})[0] == "good"
    assert fresh.classify(case, 130, "uss-slam: interrupted", {}, {}, {})[0] == "poor"


@pytest.mark.parametrize("kind", ["gint", "gterm", "int2"])
def test_a_group_or_repeated_signal_is_held_to_the_interrupt_contract(fresh, kind) -> None:
    case = fresh.Case("c", "uss-slam", f"{kind}:4", (), {}, (), "out_dir={C}/o")
    want = 143 if kind == "gterm" else 130
    line = "uss-slam: interrupted" + (" (SIGTERM)" if kind == "gterm" else "")
    assert fresh.classify(case, want, line, {}, {}, {})[0] == "good"
    assert fresh.classify(case, 1, line, {}, {}, {})[0] == "poor"


CHILD = """
import signal, sys, time
seen = []
signal.signal(signal.SIGINT, lambda *a: seen.append(1))
print("ready", flush=True)
end = time.monotonic() + 2.5
while time.monotonic() < end:
    time.sleep(0.05)
sys.exit(len(seen))
"""


@pytest.mark.parametrize(("kind", "code"), [("int2", 2), ("gint", 1), ("stop", 0)])
def test_the_runner_delivers_each_kind_of_signal(fresh, kind, code) -> None:
    """``int2`` presses Ctrl-C twice, ``gint`` once to the group, ``stop`` none (SIGSTOP, then
    SIGCONT: the child runs on and ends as it would)."""
    import subprocess

    proc = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    assert proc.stdout.readline().strip() == "ready"
    fresh._signal(proc, kind)
    assert proc.wait(timeout=30) == code


@pytest.mark.parametrize(
    ("code", "err", "verdict"),
    [
        (1, "", "good"),  # nothing on stderr, as uss-traj with a closed pipe
        (1, "uss-traj: error: stdout: cannot write the output (Broken pipe)", "good"),
        (0, "", "poor"),  # the output was not delivered, yet exit code 0
        (1, "uss-traj: error: GT: no pose", "poor"),  # a line that does not name stdout
        (120, "Exception ignored in: <_io.TextIOWrapper name='<stdout>'>", "poor"),
    ],
)
def test_a_pipe_case_expects_exit_1_and_at_most_a_line_on_stdout(fresh, code, err, verdict):
    case = _case(fresh, "uss-traj", "pipe", "ate {gt} {est}")
    assert fresh.classify(case, code, err, {}, {}, {})[0] == verdict


@pytest.mark.parametrize(
    ("code", "err", "verdict"),
    [
        (
            1,
            "uss-train: error: model.poly_power: expected a number > 0, got -1\n"
            "uss-train: 1 of 2 jobs failed:\n  model.poly_power=-1",
            "good",
        ),  # fmt: skip
        (0, "", "poor"),
        (1, "uss-train: error: seed: expected an integer", "poor"),  # not the failing key
    ],
)
def test_a_jobs_case_expects_exit_1_and_the_failing_key(fresh, code, err, verdict) -> None:
    case = fresh.Case("c", "uss-train", "jobs", (), {}, ("model.poly_power",), "-m")
    assert fresh.classify(case, code, err, {}, {"sweep/0/x.ckpt": "new"}, {})[0] == verdict


def test_stdin_closed_and_stdout_a_closed_pipe_reach_the_process(fresh, tmp_path) -> None:
    """``STDIN=closed``: fd 0 is closed; ``STDOUT=pipe``: a write to stdout fails with EPIPE."""
    case = fresh.Case("c", "uss-traj", "ok", (), {"STDIN": "closed", "STDOUT": "pipe"}, (), "")
    probe = (
        "import os, sys\n"
        "try:\n    os.fstat(0); closed = False\nexcept OSError:\n    closed = True\n"
        "try:\n    os.write(1, b'x'); broken = False\nexcept BrokenPipeError:\n    broken = True\n"
        "sys.exit(0 if closed and broken and 'STDIN' not in os.environ else 3)"
    )
    code, err = _probe(fresh, case, probe, tmp_path)
    assert code == 0, err


def test_the_screen_tells_the_shell_states_apart(fresh, tmp_path, monkeypatch) -> None:
    """A closed pipe as stdout is another shell state than ``/dev/full``: not a repeat of an
    earlier ``STDOUT=full`` case of the script, whereas the same state is (screened against the
    six sets before the seventh, which tried the closed pipe for every script)."""
    import screen_cases

    monkeypatch.setattr(screen_cases, "EARLIER", screen_cases.EARLIER[:6])
    cases = tmp_path / "cases.txt"
    cases.write_text(
        "p | uss-traj | pipe | - | STDOUT=pipe | - | ate {gt} {est} --bands 0.375\n"
        "f | uss-traj | error | - | STDOUT=full | - | ate {gt} {est} --bands 0.375\n"
    )
    found = screen_cases.screen(cases)
    assert not any(f.startswith("p: ") for f in found), found
    assert any(f.startswith("f: changes the environment") for f in found), found


def _tiny_sequence(seq: Path) -> None:
    import numpy as np
    from PIL import Image

    (seq / "rgb").mkdir(parents=True)
    rows = []
    for i in range(3):
        pixels = np.random.default_rng(i).integers(0, 255, (12, 16, 3), dtype=np.uint8)
        Image.fromarray(pixels).save(seq / "rgb" / f"{i}.5.png")
        rows.append(f"{i}.5 rgb/{i}.5.png")
    (seq / "rgb.txt").write_text("# colour images\n" + "\n".join(rows) + "\n")


def test_the_eighth_sets_image_forms_are_what_they_say(fresh, tmp_path) -> None:
    """studies/fresh_setups8.py: each colour frame form holds the frame's picture in the form
    its name says (an animated PNG whose default image is the frame; a 16-bit RGB PNG; a PNG
    renamed .jpg and listed so; a folder in the frame's place)."""
    import numpy as np
    from fresh_setups8 import EIGHTH
    from PIL import Image

    forms = {"rgb_apng": "RGB", "rgb_la": "LA", "rgb_1bit": "1", "rgb_palette_2bit": "P",
             "rgb_rgb16": None, "rgb_png_named_jpg": "RGB", "rgb_folder_as_frame": None}  # fmt: skip
    for name, mode in forms.items():
        c = tmp_path / name
        _tiny_sequence(c / "seq")
        original = np.asarray(Image.open(c / "seq" / "rgb" / "2.5.png").convert("RGB"))
        EIGHTH[name](c, {})
        if name == "rgb_folder_as_frame":
            assert (c / "seq" / "rgb" / "2.5.png").is_dir()
            continue
        if name == "rgb_png_named_jpg":
            assert "rgb/2.5.jpg" in (c / "seq" / "rgb.txt").read_text()
            frame = c / "seq" / "rgb" / "2.5.jpg"
            assert frame.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        else:
            frame = c / "seq" / "rgb" / "2.5.png"
        if name == "rgb_rgb16":
            import cv2

            image = cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)
            assert image.dtype == np.uint16 and image.shape == (12, 16, 3)
            continue
        image = Image.open(frame)
        assert image.mode == mode, name
        if name == "rgb_apng":
            assert getattr(image, "is_animated", False) is False or image.n_frames == 1
            assert b"acTL" in frame.read_bytes()
            assert np.array_equal(np.asarray(image.convert("RGB")), original)


def test_the_eighth_sets_parts_reach_every_template(fresh) -> None:
    """Every case of studies/fresh_cases8.txt names known setups, and its argv and environment
    are formed with the path parts of studies/fresh_setups8.py (a newline kept in one argument,
    the 4401-digit number whole)."""
    cases = fresh.read_cases(STUDIES / "fresh_cases8.txt")
    names = ("W", "seq", "seq2", "voc", "ckpt", "onnx", "onnx2", "gt", "est", "vocab", "slam")
    paths = {**{n: f"/w/{n}" for n in names}, "C": "/c", "R": "/r", "tum": "/t", **fresh.LONG}
    for case in cases:
        assert all(s in fresh.SETUPS for s in case.setup), case.id
        argv = fresh._argv(case, paths)
        for value in case.env.values():
            value.format(**paths)
        if "{nl}" in case.argv:
            assert any("new\nline" in a for a in argv), case.id
        if "{big}" in case.argv:
            assert any(a.endswith("1" + "0" * 4400) for a in argv), case.id

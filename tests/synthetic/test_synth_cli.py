"""``uss-synth``: what it writes, and one-line errors with exit code 2 that write nothing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from uss_slam.synthetic import OutputExistsError, SynthArgumentError, render_sequence
from uss_slam.synthetic.cli import main
from uss_slam.synthetic.output import OUTPUT_MARKER, OUTPUT_MARKER_TEXT


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    code = "import sys; from uss_slam.synthetic.cli import main; sys.exit(main())"
    return subprocess.run(
        [sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["sequence", "--preset", "running_xyz", "--out", "x"], "unknown preset 'running_xyz'"),
        (
            ["sequence", "--preset", "walking_xyz", "--size", "640-480", "--out", "x"],
            "WIDTHxHEIGHT",
        ),
        (["sequence", "--preset", "walking_xyz", "--size", "8x8", "--out", "x"], "between 16x16"),
        (
            ["sequence", "--preset", "walking_xyz", "--frames", "1", "--out", "x"],
            "expected an integer >= 2",
        ),
        (["sequence", "--preset", "walking_xyz", "--frames", "ten", "--out", "x"], "integer"),
        (  # the loop preset's turn and its return: at least 450 frames (its help says why)
            ["sequence", "--preset", "loop", "--frames", "449", "--out", "x"],
            "argument --frames: the loop preset needs at least 450 frames",
        ),
        (
            ["sequence", "--preset", "walking_xyz", "--style", "anime", "--out", "x"],
            "invalid choice",
        ),
        (["sequence", "--preset", "walking_xyz"], "--out"),
        (["voc", "--images", "0", "--out", "x"], "expected an integer >= 1"),
        (["voc", "--outfits", "plain", "--out", "x"], "invalid choice: 'plain'"),
        (["demo", "--out", "x"], "invalid choice: 'demo'"),  # the demo data: uss-demo
        (["render", "--out", "x"], "invalid choice"),
    ],
)
def test_bad_arguments(args: list[str], message: str, tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    code = exit_info.value.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert list(tmp_path.iterdir()) == []


def test_bad_argument_exits_2_in_a_process(tmp_path: Path) -> None:
    out = _run(["sequence", "--preset", "nope", "--out", "seq"], tmp_path)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and "unknown preset" in out.stderr
    assert list(tmp_path.iterdir()) == []


def test_existing_output_needs_overwrite(tmp_path: Path, capsys) -> None:
    out = tmp_path / "seq"
    args = ["sequence", "--preset", "static_xyz", "--frames", "2", "--size", "32x24",
            "--out", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    first = (out / "rgb.txt").stat().st_mtime_ns
    assert (out / OUTPUT_MARKER).read_text() == OUTPUT_MARKER_TEXT
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not empty" in err and str(out) in err
    assert (out / "rgb.txt").stat().st_mtime_ns == first
    assert main([*args, "--overwrite"]) == 0  # a uss-synth output: replaced
    assert (out / "rgb.txt").stat().st_mtime_ns != first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]  # no partial sibling left


@pytest.mark.parametrize("marker", [None, "synthetic.yaml", "demo.yaml"])
def test_overwrite_refuses_a_folder_uss_synth_did_not_write(
    tmp_path: Path, capsys, marker: str | None
) -> None:
    out = tmp_path / "VOC2012"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    if marker:  # a yaml that is not ours does not count either
        (out / marker).write_text("generator: labelme\n")
    args = ["voc", "--images", "1", "--size", "32x24", "--out", str(out), "--quiet"]
    assert main([*args, "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"uss-synth: error: --out={out}: not a uss-synth output (no {OUTPUT_MARKER} or "
        "synthetic.yaml in it); refusing to overwrite it"
    )
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["keep.txt", *([marker] if marker else [])]
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["VOC2012"]


def test_overwrite_accepts_outputs_of_earlier_versions(tmp_path: Path) -> None:
    """Folders written before the marker existed: a sequence's synthetic.yaml names uss-synth."""
    out = tmp_path / "seq"
    out.mkdir()
    (out / "synthetic.yaml").write_text("generator: uss-synth\npreset: static_xyz\n")
    args = ["sequence", "--preset", "static_xyz", "--frames", "2", "--size", "32x24",
            "--out", str(out), "--quiet", "--overwrite"]  # fmt: skip
    assert main(args) == 0 and (out / OUTPUT_MARKER).is_file()


def test_api_errors(tmp_path: Path) -> None:
    with pytest.raises(SynthArgumentError, match="unknown preset"):
        render_sequence(tmp_path / "a", preset="nope", frames=2)
    with pytest.raises(SynthArgumentError, match="frames must be an integer >= 2"):
        render_sequence(tmp_path / "a", preset="static_xyz", frames=1)
    with pytest.raises(SynthArgumentError, match="unknown style"):
        render_sequence(tmp_path / "a", preset="static_xyz", frames=2, style="anime")
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "x").write_text("")
    with pytest.raises(OutputExistsError, match="not empty"):
        render_sequence(tmp_path / "b", preset="static_xyz", frames=2, size=(32, 24))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]


def test_failure_while_rendering_leaves_nothing(tmp_path: Path, monkeypatch) -> None:
    from uss_slam.synthetic import sequence

    calls = []

    def broken(self, index):
        calls.append(index)
        if index == 1:
            raise RuntimeError("disk on fire")
        return original(self, index)

    original = sequence.SequenceRenderer.frame
    monkeypatch.setattr(sequence.SequenceRenderer, "frame", broken)
    with pytest.raises(RuntimeError, match="disk on fire"):
        render_sequence(tmp_path / "seq", preset="static_xyz", frames=3, size=(32, 24))
    assert calls == [0, 1]
    assert list(tmp_path.iterdir()) == []


def test_help_documents_everything(capsys) -> None:
    for command in ([], ["sequence"], ["voc"]):
        with pytest.raises(SystemExit) as exit_info:
            main([*command, "--help"])
        assert exit_info.value.code == 0
        text = capsys.readouterr().out
        if command == ["sequence"]:
            for word in ("--preset", "--frames", "--size", "--seed", "--style", "--out",
                         "--overwrite", "walking_halfsphere", "static_xyz", "5000", "--outfits"):  # fmt: skip
                assert word in text, word
        if command == ["voc"]:
            assert "--outfits {classic,varied,all}" in text and "varied = every kind of" in text
            assert "--style {source,target,mixed}" in text and "labelled" in text and "COCO" in text
        if command == []:
            assert "{sequence,voc}" in text and "killed" in text and OUTPUT_MARKER in text

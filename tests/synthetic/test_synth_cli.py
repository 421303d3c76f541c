"""``uss-synth``: what it writes, and one-line errors with exit code 2 that write nothing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from uss_slam.synthetic import OutputExistsError, SynthArgumentError, render_sequence
from uss_slam.synthetic.cli import main


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
        (["sequence", "--preset", "walking_xyz", "--frames", "1", "--out", "x"], "must be >= 2"),
        (["sequence", "--preset", "walking_xyz", "--frames", "ten", "--out", "x"], "integer"),
        (
            ["sequence", "--preset", "walking_xyz", "--style", "anime", "--out", "x"],
            "invalid choice",
        ),
        (["sequence", "--preset", "walking_xyz"], "--out"),
        (["voc", "--images", "0", "--out", "x"], "must be >= 1"),
        (["demo", "--slam-frames", "1", "--out", "x"], "must be 0 (skip) or >= 2"),
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
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    args = [
        "sequence",
        "--preset",
        "static_xyz",
        "--frames",
        "2",
        "--size",
        "32x24",
        "--out",
        str(out),
    ]
    assert main([*args, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not empty" in err and str(out) in err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]  # no partial sibling left
    assert main([*args, "--quiet", "--overwrite"]) == 0
    assert not (out / "keep.txt").exists() and (out / "rgb.txt").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


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
    for command in ([], ["sequence"], ["voc"], ["demo"]):
        with pytest.raises(SystemExit) as exit_info:
            main([*command, "--help"])
        assert exit_info.value.code == 0
        text = capsys.readouterr().out
        if command == ["sequence"]:
            for word in ("--preset", "--frames", "--size", "--seed", "--style", "--out",
                         "--overwrite", "walking_halfsphere", "static_xyz", "5000"):  # fmt: skip
                assert word in text, word
        if command == ["demo"]:
            for word in ("--voc-images", "--train-frames", "--slam-frames", "0 to skip"):
                assert word in text, word


def test_demo_small(tmp_path: Path, capsys) -> None:
    out = tmp_path / "demo"
    args = ["demo", "--out", str(out), "--quiet", "--voc-images", "5", "--voc-size", "64x48",
            "--train-frames", "3", "--val-frames", "2", "--train-size", "48x32",
            "--slam-frames", "2", "--slam-size", "64x48", "--workers", "1"]  # fmt: skip
    assert main(args) == 0
    text = capsys.readouterr().out
    assert str(out.resolve()) in text
    assert "voc/VOCdevkit/VOC2012: 4 train + 1 val images, 64x48" in text
    for name in ("walking_xyz", "walking_rpy", "walking_halfsphere", "sitting_static"):
        assert f"target_train/{name}: 3 frames, 48x32, target style" in text
        assert (out / "target_train" / name / "groundtruth.txt").is_file()
    assert "target_val/walking_xyz: 2 frames, 48x32" in text
    assert "slam/walking_xyz: 2 frames, 64x48" in text and "slam/static_xyz: 2 frames" in text
    assert "person" in text and "%" in text
    # --reuse keeps a complete demo made with the same arguments, and only then
    stamp = (out / "slam" / "walking_xyz" / "rgb.txt").stat().st_mtime_ns
    assert main([*args, "--reuse"]) == 0
    assert "reusing" in capsys.readouterr().out
    assert (out / "slam" / "walking_xyz" / "rgb.txt").stat().st_mtime_ns == stamp
    changed = [a if a != "5" else "6" for a in args]  # --voc-images 6
    assert main([*changed, "--reuse"]) == 2  # different arguments: not reusable, not empty
    assert "not empty" in capsys.readouterr().err
    # two worker processes produce the same files
    again = tmp_path / "again"
    assert main([*args[:2], str(again), *args[3:-1], "2"]) == 0
    files = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    assert all((out / f).read_bytes() == (again / f).read_bytes() for f in files)

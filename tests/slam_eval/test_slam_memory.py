"""``uss-slam``'s memory estimate (slam_eval/memory.py): its parts and the keys that drive them,
and a run whose estimate exceeds the memory available refused before any work (a fake small
limit: no test needs a machine with little memory)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module

from uss_slam.core import resources
from uss_slam.slam_eval.memory import FRAME_BYTES_PER_PIXEL, estimate, image_size
from uss_slam.slam_eval.run import main


def _cfg(overrides: list[str]):
    with initialize_config_module("uss_slam.configs", version_base="1.3"):
        return compose("slam_eval", overrides=["sequence.path=x", *overrides])


def test_parts_follow_their_settings(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0}, raising=False)  # auto: threads
    model = tmp_path / "m.onnx"
    model.write_bytes(b"\0" * 1000)
    base = estimate(_cfg([]), 300, (640, 480))
    assert set(base.parts) == {"frames read ahead", "the map"}
    ahead = estimate(_cfg(["slam.prefetch=256"]), 300, (640, 480))
    grown = ahead.parts["frames read ahead"].bytes - base.parts["frames read ahead"].bytes
    assert grown == 252 * FRAME_BYTES_PER_PIXEL * 640 * 480
    assert [p.lower for p in ahead.drivers()] == ["slam.prefetch"]
    longer = estimate(_cfg([]), 3000, (640, 480))
    assert longer.parts["the map"].bytes == 10 * base.parts["the map"].bytes
    assert "sequence.max_frames" in longer.drivers()[0].lower
    onnx = estimate(_cfg(["segmenter=onnx", f"segmenter.path={model}", "segmenter.threads=4",
                          "slam.repeats=3"]), 300, (640, 480))  # fmt: skip
    assert {"the segmenter", "repeats"} <= set(onnx.parts)
    assert onnx.parts["the segmenter"].keys == "segmenter.threads=4, slam.workers=2"
    process = estimate(_cfg(["slam.prefetch_mode=process"]), 300, (640, 480))
    assert process.need > base.need
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1}, raising=False)
    auto = estimate(_cfg([]), 300, (640, 480))  # a second core: auto is the worker process
    assert auto.parts["the frame worker process"].keys == "slam.prefetch_mode=auto"
    assert auto.need == process.need


def test_image_size_reads_the_png_header(synthetic_sequence) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=2, size=(64, 48))
    assert image_size(sorted((seq / "rgb").iterdir())[0]) == (64, 48)


def test_a_run_that_cannot_fit_is_one_line_before_any_work(
    tmp_path: Path, monkeypatch, capsys, synthetic_sequence
) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=8, size=(160, 120))
    monkeypatch.delenv(resources.MEMORY_OVERRIDE, raising=False)
    monkeypatch.setattr(resources, "available_memory",
                        lambda: (1_000_000, "its cgroup's memory limit"))  # fmt: skip
    out = tmp_path / "o"
    argv = ["uss-slam", f"sequence.path={seq}", f"out_dir={out}", "progress=false",
            "slam.prefetch_mode=thread", "slam.prefetch=200"]  # fmt: skip
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(SystemExit) as stop:
        main()
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 1
    assert len(err.splitlines()) == 1, err
    assert err.startswith("uss-slam: error: slam.prefetch=200, slam.workers=2: this run ")
    assert "1 MB available (its cgroup's memory limit); lower slam.prefetch" in err
    assert "USS_SLAM_NO_MEMORY_CHECK=1" in err
    assert not (out / "run.json").exists() and not (out / "trajectory.txt").exists()
    monkeypatch.setenv(resources.MEMORY_OVERRIDE, "1")  # the user's call: the run goes ahead
    monkeypatch.setattr(sys, "argv", [*argv[:-1], "slam.prefetch=2", "sequence.max_frames=4"])
    main()
    assert (out / "run.json").is_file()


def test_orbslam3_is_estimated_as_the_harness_is(tmp_path: Path) -> None:
    """``system=orbslam3``: its process, the vocabulary by its file, the map at
    ``system.n_features``, and with a segmenter the masks of every frame."""
    from uss_slam.slam_eval.memory import PROCESS_BYTES, VOCABULARY_COPIES, estimate_orbslam3

    vocab = tmp_path / "voc.txt"
    with open(vocab, "wb") as f:
        f.truncate(10**8)  # a sparse file: 100 MB by its size, nothing on the disk
    base = estimate_orbslam3(_cfg(["system=orbslam3", f"system.vocabulary={vocab}"]), 300,
                             (640, 480))  # fmt: skip
    assert set(base.parts) == {"the ORB-SLAM3 process", "the vocabulary", "the map"}
    assert base.parts["the ORB-SLAM3 process"].bytes == PROCESS_BYTES
    assert base.parts["the vocabulary"].bytes == VOCABULARY_COPIES * 10**8
    more = estimate_orbslam3(_cfg(["system=orbslam3", f"system.vocabulary={vocab}",
                                   "system.n_features=4000"]), 300, (640, 480))  # fmt: skip
    assert more.parts["the map"].bytes == 4 * base.parts["the map"].bytes
    labels = estimate_orbslam3(_cfg(["system=orbslam3", f"system.vocabulary={vocab}",
                                     "segmenter=labels"]), 300, (640, 480))  # fmt: skip
    assert labels.parts["the masks"].bytes == 300 * 640 * 480


def test_an_orbslam3_run_that_cannot_fit_is_one_line_before_any_work(
    tmp_path: Path, monkeypatch, capsys, synthetic_sequence
) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=8, size=(160, 120))
    vocab = tmp_path / "voc.txt"
    with open(vocab, "wb") as f:
        f.truncate(10**9)
    monkeypatch.delenv(resources.MEMORY_OVERRIDE, raising=False)
    monkeypatch.setattr(resources, "available_memory",
                        lambda: (500_000_000, "its cgroup's memory limit"))  # fmt: skip
    out = tmp_path / "o"
    monkeypatch.setattr(sys, "argv", ["uss-slam", f"sequence.path={seq}", f"out_dir={out}",
                                      "progress=false", "system=orbslam3",
                                      f"system.vocabulary={vocab}"])  # fmt: skip
    with pytest.raises(SystemExit) as stop:
        main()
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 1
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"uss-slam: error: system.vocabulary={vocab}: this run (")
    assert "500 MB available (its cgroup's memory limit); lower system.vocabulary" in err
    assert not (out / "run.json").exists() and not (out / "trajectory.txt").exists()

"""``uss-slam system=orbslam3``: the settings file, the blanking of dynamic pixels, the checks of
bad inputs, and a real ORB-SLAM3 run (pyorbslam3, optional) with a vocabulary built in the test."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.tum_io import TUM_CAMERAS, read_trajectory
from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.scoring.evaluation import EvalConfig
from uss_slam.slam_eval.scoring.repeats import median_index
from uss_slam.slam_eval.segmenters.base import LabelsSegmenter, NoSegmenter
from uss_slam.slam_eval.sequence import Frame, TumSequence
from uss_slam.slam_eval.systems.orbslam3.config import OrbSlam3Config, check_vocabulary
from uss_slam.slam_eval.systems.orbslam3.masking import (
    blank_dynamic,
    compute_masks,
    dynamic_mask,
    fill_dynamic,
    read_filled,
)
from uss_slam.slam_eval.systems.orbslam3.settings import check_settings, frame_rate, settings_yaml
from uss_slam.slam_eval.systems.orbslam3.system import SequenceSpec, run_orbslam3
from uss_slam.slam_eval.systems.orbslam3.vocabulary import build_from_sequences, read_vocabulary


def _node(storage: cv2.FileStorage, key: str) -> float:
    return storage.getNode(key).real()


def test_settings_file_holds_the_camera_and_orb_settings(tmp_path: Path) -> None:
    cam = TUM_CAMERAS["fr1"]  # with distortion
    path = tmp_path / "s.yaml"
    path.write_text(settings_yaml(cam, OrbSlam3Config(), fps=30))
    assert path.read_text().startswith("%YAML:1.0\n")
    info = check_settings(path, (640, 480))
    assert (info.width, info.height, info.depth_factor, info.rgb) == (640, 480, 1.0, True)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.getNode("File.version").string() == "1.0"
    assert fs.getNode("Camera.type").string() == "PinHole"
    got = [_node(fs, f"Camera1.{k}") for k in ("fx", "fy", "cx", "cy")]
    assert got == [cam.fx, cam.fy, cam.cx, cam.cy]
    dist = [_node(fs, f"Camera1.{k}") for k in ("k1", "k2", "p1", "p2", "k3")]
    assert dist == list(cam.distortion)
    for key, value in {
        "Camera.fps": 30,
        "Camera.RGB": 1,
        "ORBextractor.nFeatures": 1000,
        "ORBextractor.nLevels": 8,
        "ORBextractor.iniThFAST": 20,
        "ORBextractor.minThFAST": 7,
    }.items():
        assert fs.getNode(key).isInt() and int(fs.getNode(key).real()) == value, key
    assert _node(fs, "ORBextractor.scaleFactor") == 1.2
    assert _node(fs, "Stereo.b") == 0.0747 and _node(fs, "Stereo.ThDepth") == 40.0
    assert _node(fs, "RGBD.DepthMapFactor") == 1.0
    fs.release()
    # fr3 has no distortion: k1..p2 are 0 and k3 is written too (5 coefficients)
    text = settings_yaml(TUM_CAMERAS["fr3"], OrbSlam3Config(), fps=30)
    assert "Camera1.k1: 0.0\n" in text and "Camera1.k3: 0.0\n" in text


def _settings_without(tmp_path: Path, key: str, replacement: str | None = None) -> Path:
    text = settings_yaml(TUM_CAMERAS["fr3"], OrbSlam3Config(), fps=30)
    lines = [
        (replacement if replacement is not None else None) if line.startswith(key + ":") else line
        for line in text.splitlines()
    ]
    path = tmp_path / "bad.yaml"
    path.write_text("\n".join(line for line in lines if line is not None) + "\n")
    return path


@pytest.mark.parametrize(
    ("key", "replacement", "message"),
    [
        ("Viewer.KeyFrameSize", None, "missing Viewer.KeyFrameSize"),
        ("Camera.fps", "Camera.fps: 29.97", "Camera.fps must be an integer"),
        ("File.version", None, 'File.version: "1.0"'),
        ("Camera.type", 'Camera.type: "KannalaBrandt8"', 'must be "PinHole"'),
        ("Camera.width", "Camera.width: 320", "is 320x480 but the sequence's images are 640x480"),
        ("RGBD.DepthMapFactor", "RGBD.DepthMapFactor: 0.0", "DepthMapFactor must be > 0"),
    ],
)
def test_bad_settings_are_one_line(tmp_path: Path, key: str, replacement, message: str) -> None:
    path = _settings_without(tmp_path, key, replacement)
    with pytest.raises(DataFormatError) as info:
        check_settings(path, (640, 480))
    assert message in str(info.value) and str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_unreadable_settings_and_bad_config_values(tmp_path: Path) -> None:
    (tmp_path / "x.yaml").write_text("%YAML:1.0\n: : [\n")
    with pytest.raises(DataFormatError, match="not an OpenCV YAML file"):
        check_settings(tmp_path / "x.yaml")
    with pytest.raises(DataFormatError, match="file not found"):
        check_settings(tmp_path / "none.yaml")
    with pytest.raises(UssSlamError, match=r"system.repeats: expected an integer >= 1, got 0"):
        OrbSlam3Config(repeats=0)
    with pytest.raises(
        UssSlamError, match=r"system.blank_value: expected an integer >= 0 and <= 255, got 300"
    ):
        OrbSlam3Config(blank_value=300)
    with pytest.raises(UssSlamError, match=r"system.min_fast: expected an integer <= system.ini"):
        OrbSlam3Config(min_fast=21)
    with pytest.raises(UssSlamError, match="4 or 5 distortion coefficients"):
        cam = TUM_CAMERAS["fr3"]
        eight = type(cam)(cam.fx, cam.fy, cam.cx, cam.cy, 640, 480, (0.0,) * 8)
        settings_yaml(eight, OrbSlam3Config(), fps=30)


def test_missing_vocabulary_names_the_key_and_the_builder(tmp_path: Path) -> None:
    for value, expected in ((None, "system.vocabulary is not set"), ("", "is not set")):
        with pytest.raises(UssSlamError) as info:
            check_vocabulary(value)
        assert expected in str(info.value) and "uss-vocab build" in str(info.value)
    with pytest.raises(UssSlamError) as info:
        check_vocabulary(str(tmp_path / "voc.txt"))
    message = str(info.value)
    assert message.startswith(f"system.vocabulary={tmp_path / 'voc.txt'}: file not found")
    assert "uss-vocab build" in message and "\n" not in message
    (tmp_path / "bin.txt").write_text("not a vocabulary\n")
    with pytest.raises(UssSlamError, match=r"system.vocabulary=.*'k L scoring weighting'"):
        check_vocabulary(str(tmp_path / "bin.txt"))


def test_a_vocabulary_of_another_descriptor_is_one_line_naming_its_line(tmp_path: Path) -> None:
    """A DBoW2 text vocabulary of BRISK's 64 bytes or SURF's 64 floats per node has ORB's header
    but not ORB's nodes: stopped before ORB-SLAM3 loads it."""
    orb = "0 0 " + " ".join(["7"] * 32) + " 0.5\n"
    (tmp_path / "orb.txt").write_text("10 2 0 0\n" + orb * 3)
    assert check_vocabulary(str(tmp_path / "orb.txt")) == tmp_path / "orb.txt"
    for name, node in (
        ("brisk.txt", "0 0 " + " ".join(["200"] * 64) + " 0.5\n"),
        ("surf.txt", "0 0 " + " ".join(["0.125"] * 64) + " 0.5\n"),
        ("floats32.txt", "0 0 " + " ".join(["0.5"] * 32) + " 0.5\n"),
    ):
        (tmp_path / name).write_text("10 2 0 0\n" + orb + node)
        with pytest.raises(UssSlamError) as info:
            check_vocabulary(str(tmp_path / name))
        message = str(info.value)
        assert message.startswith(f"system.vocabulary={tmp_path / name}: line 3: a node of ")
        assert "built for another descriptor" in message and "\n" not in message
    assert "64 descriptor values" in str(_error(check_vocabulary, str(tmp_path / "brisk.txt")))
    assert "64 descriptor floats" in str(_error(check_vocabulary, str(tmp_path / "surf.txt")))


def _error(fn, *args) -> UssSlamError:
    with pytest.raises(UssSlamError) as info:
        fn(*args)
    return info.value


def test_blanked_pixels_are_exactly_the_dilated_mask() -> None:
    h, w = 40, 50
    labels = np.zeros((h, w), np.uint8)
    labels[20, 25] = 1  # person: dynamic
    labels[5, 5] = 2  # chair: static, left alone
    semantic = SemanticFilter(dynamic_classes=["person"], dilation=3)
    frame = Frame(0, 0.0, np.zeros((h, w, 3), np.uint8), labels, np.ones((h, w), np.float32))
    mask = dynamic_mask(frame, labels, [semantic])
    # the dilation is the harness's: an elliptic 7x7 structuring element centred on the pixel
    expected = np.zeros((h, w), bool)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)).astype(bool)
    expected[17:24, 22:29] = disc
    assert np.array_equal(mask, expected)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
    out_rgb, out_depth = blank_dynamic(rgb, depth, mask, 128)
    assert np.all(out_rgb[mask] == 128) and np.all(out_depth[mask] == 0.0)
    assert np.array_equal(out_rgb[~mask], rgb[~mask])
    assert np.array_equal(out_depth[~mask], depth[~mask])
    assert out_rgb is not rgb and out_depth is not depth  # the frame is not modified
    same_rgb, same_depth = blank_dynamic(rgb, depth, np.zeros((h, w), bool))
    assert same_rgb is rgb and same_depth is depth


def test_inpainting_leaves_a_weaker_edge_across_a_partly_masked_walker() -> None:
    """A mask over the left part of a walker: grey leaves a strong edge across him, inpainting
    continues his colour; pixels outside the mask are never changed."""
    h, w = 60, 80
    rgb = np.full((h, w, 3), 90, np.uint8)
    rgb[10:50, 20:60] = (200, 60, 60)  # the walker
    mask = np.zeros((h, w), bool)
    mask[5:55, 10:40] = True  # covers his left half only
    depth = np.full((h, w), 2.0, np.float32)
    grey_rgb, grey_depth = blank_dynamic(rgb, depth, mask, 128)
    inpainted = fill_dynamic(rgb, mask, "inpaint")
    for out in (grey_rgb, inpainted):
        assert np.array_equal(out[~mask], rgb[~mask])

    def edge(img: np.ndarray) -> float:  # across the mask's right edge, on the walker
        return float(np.abs(img[15:45, 39].astype(int) - img[15:45, 40].astype(int)).mean())

    assert edge(grey_rgb) > 60 and edge(inpainted) < 15
    rgb_filled, depth_filled = blank_dynamic(rgb, depth, mask, 128, inpainted)
    assert rgb_filled is inpainted and np.array_equal(depth_filled, grey_depth)
    assert np.all(depth_filled[mask] == 0.0) and np.all(depth_filled[~mask] == 2.0)
    with pytest.raises(UssSlamError, match="system.blank_fill='blur': expected one of grey"):
        fill_dynamic(rgb, mask, "blur")
    with pytest.raises(
        UssSlamError, match="system.blank_fill: expected one of 'grey', 'inpaint', got 'blur'"
    ):
        OrbSlam3Config(blank_fill="blur")


def test_the_inpainted_frames_are_written_once_losslessly(synthetic_sequence, tmp_path) -> None:
    seq = TumSequence(synthetic_sequence(preset="walking_xyz", frames=4, size=(160, 120)),
                      load_labels=True)  # fmt: skip
    semantic = SemanticFilter(["person"], 5)
    folder = tmp_path / "filled"
    masks = compute_masks(seq, LabelsSegmenter(), [semantic], progress=False, fill_dir=folder)
    assert masks.fill_ms > 0
    written = 0
    for frame in seq.frames():
        mask = dynamic_mask(frame, frame.labels, [semantic])
        filled = read_filled(folder, frame.index)
        if not mask.any():
            assert filled is None
            continue
        written += 1
        assert np.array_equal(filled, fill_dynamic(frame.rgb, mask, "inpaint"))
    assert written == len(list(folder.iterdir())) > 0
    grey = compute_masks(seq, LabelsSegmenter(), [semantic], progress=False)
    assert grey.fill_ms == 0.0 and np.array_equal(grey.packed, masks.packed)


def test_median_run_and_frame_rate() -> None:
    assert median_index([0.3, 0.1, 0.2]) == 2
    assert median_index([0.3, 0.1]) == 1  # an even count: the lower middle run
    assert median_index([None, 0.5, 0.1]) == 1  # a run without ATE counts as the worst
    assert median_index([None]) == 0
    assert frame_rate(np.arange(10) / 30.0) == 30
    assert frame_rate(np.arange(10) / 15.0) == 15
    assert frame_rate(np.array([1.0])) == 30


# ------------------------------------------------------------------ the real ORB-SLAM3


@pytest.mark.slow
def test_orbslam3_tracks_with_a_vocabulary_built_from_frames(
    synthetic_sequence, tmp_path: Path
) -> None:
    pytest.importorskip("pyorbslam3")
    seq = synthetic_sequence(preset="static_xyz", frames=30, size=(320, 240))
    vocab = tmp_path / "voc.txt"
    built = build_from_sequences([seq], vocab, k=8, levels=3, stride=3)
    assert read_vocabulary(vocab).n_nodes == built.nodes
    out = tmp_path / "run"
    data = run_orbslam3(
        SequenceSpec(str(seq)),
        LabelsSegmenter(),
        [SemanticFilter(["person"], 5)],
        OrbSlam3Config(vocabulary=str(vocab), repeats=2, realtime=False),
        EvalConfig(),
        out,
        progress=False,
    )
    for name in ("trajectory.txt", "metrics.json", "report.md", "orbslam3_settings.yaml"):
        assert (out / name).is_file(), name
    for name in ("trajectory.png", "ate.png", "repeats.png"):
        assert (out / name).is_file(), name
    assert json.loads((out / "metrics.json").read_text()) == json.loads(json.dumps(data))
    assert data["frames"] == 30 and len(data["repeats"]) == 2
    for r in data["repeats"]:
        assert sum(r["tracking_states"].values()) == 30
        assert (out / r["trajectory"]).is_file()
        assert (out / "repeats" / f"orbslam3_{r['index']}.log").is_file()
    median = data["repeats"][data["median_repeat"]]
    assert (out / "trajectory.txt").read_bytes() == (out / median["trajectory"]).read_bytes()
    assert data["ate_rmse_repeats"]["median"] == median["ate_rmse"] == data["ate"]["rmse"]
    rmses = [r["ate_rmse"] for r in data["repeats"]]
    assert data["ate_rmse_repeats"]["min"] == min(rmses)
    assert data["ate_rmse_repeats"]["max"] == max(rmses)
    # a static scene, a fixed camera model: ORB-SLAM3 initialises on the first frame and keeps
    # tracking; its error is millimetres (the synthetic depth noise), far below 5 cm
    assert data["tracking_states"] == {"OK": 30} and data["frames_without_pose"] == 0
    assert len(read_trajectory(out / "trajectory.txt")) == 30
    assert data["ate"]["rmse"] < 0.05
    assert data["segmenter"] == "labels" and data["blanked"]["dilation"] == 5
    assert 0 < data["blanked"]["fraction"] < 0.5  # the seated people are blanked

    # Without a segmenter nothing is blanked; a settings file of the user's is used as given.
    own = tmp_path / "own.yaml"
    own.write_text((out / "orbslam3_settings.yaml").read_text())
    data = run_orbslam3(
        SequenceSpec(str(seq), max_frames=10),
        NoSegmenter(),
        [SemanticFilter()],
        OrbSlam3Config(vocabulary=str(vocab), repeats=1, settings_file=str(own)),
        EvalConfig(),
        tmp_path / "plain",
        progress=False,
    )
    assert data["blanked"] is None and data["orbslam3"]["settings_file"] == str(own)
    assert data["frames"] == 10 and data["tracking_states"] == {"OK": 10}

    # Inpainted instead of grey: the same masks, the frames filled once before the repeats.
    data = run_orbslam3(
        SequenceSpec(str(seq), max_frames=10),
        LabelsSegmenter(),
        [SemanticFilter(["person"], 5)],
        OrbSlam3Config(vocabulary=str(vocab), repeats=1, realtime=False, blank_fill="inpaint"),
        EvalConfig(),
        tmp_path / "inpaint",
        progress=False,
    )
    assert data["blanked"]["fill"] == "inpaint" and data["blanked"]["fill_ms"] > 0
    # ORB-SLAM3's local mapping runs in its own thread: on a busy machine the tracker can reach
    # a frame before the map it needs (one LOST frame in 10, seen once in a full test run).
    assert sum(data["tracking_states"].values()) == 10 and data["tracking_states"]["OK"] >= 9
    assert "inpainted (" in (tmp_path / "inpaint" / "report.md").read_text()

    # Everything blanked: ORB-SLAM3 finds no corner and never initialises; every frame is
    # counted as untracked, the repeat's (empty) trajectory is kept and ATE says why it is absent.
    data = run_orbslam3(
        SequenceSpec(str(seq), max_frames=6),
        LabelsSegmenter(),
        [SemanticFilter(["background", "person", "chair", "monitor"], 0)],
        OrbSlam3Config(vocabulary=str(vocab), repeats=1, realtime=False),
        EvalConfig(),
        tmp_path / "blank",
        progress=False,
    )
    assert data["blanked"]["fraction"] == 1.0
    assert data["tracking_states"] == {"NOT_INITIALIZED": 6} and data["frames_tracked"] == 0
    assert data["frames_without_pose"] == 6 and data["ate"] is None
    assert data["ate_error"] == "only 0 frames were tracked; ATE needs 3 poses"
    assert len(read_trajectory(tmp_path / "blank" / "trajectory.txt")) == 0


# ------------------------------------------------------------------ uss-slam system=orbslam3


def _cfg(overrides: list[str]):
    from shared_helpers import compose_slam_eval

    return compose_slam_eval(overrides)


def test_system_group_composes() -> None:
    assert _cfg(["sequence.path=/x"]).system.name == "harness"  # the default is unchanged
    cfg = _cfg(["sequence.path=/x", "system=orbslam3"])
    system = cfg.system
    assert system.name == "orbslam3" and system.vocabulary is None and system.repeats == 3
    values = {k: v for k, v in system.items() if k != "name"}
    assert OrbSlam3Config(**values) == OrbSlam3Config()  # the YAML holds the defaults


def test_uss_slam_orbslam3_bad_inputs_are_one_line(synthetic_sequence, tmp_path: Path) -> None:
    pytest.importorskip("pyorbslam3")
    from uss_slam.slam_eval.run import run

    seq = synthetic_sequence(preset="static_xyz", frames=30, size=(320, 240))
    base = [f"sequence.path={seq}", "system=orbslam3", f"out_dir={tmp_path}", "progress=false"]
    with pytest.raises(UssSlamError, match=r"^system.vocabulary is not set: .*uss-vocab build"):
        run(_cfg(base))
    with pytest.raises(UssSlamError, match=r"filter 'geometry' cannot blank ORB-SLAM3's input"):
        run(_cfg([*base, "system.vocabulary=v.txt", "segmenter=labels", "filters=[geometry]"]))
    with pytest.raises(UssSlamError, match=r"filters=\['semantic'\] blank what a segmenter finds"):
        run(_cfg([*base, "system.vocabulary=v.txt", "filters=[semantic]"]))
    with pytest.raises(UssSlamError, match=r"compare= is the harness's"):
        run(_cfg([*base, "system.vocabulary=v.txt", "compare=[[flow]]"]))
    with pytest.raises(UssSlamError, match=r"segment=keyframes applies to the harness only"):
        run(_cfg([*base, "system.vocabulary=v.txt", "segment=keyframes"]))
    assert not (tmp_path / "metrics.json").exists()
    # the console script: one line on stderr, exit code 1
    proc = subprocess.run(
        [sys.executable, "-m", "uss_slam.slam_eval.run", *base[:3], "system.vocabulary=nope.txt"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 1
    assert proc.stderr.startswith("uss-slam: error: system.vocabulary=nope.txt: file not found; ")
    assert proc.stderr.count("\n") == 1 and "uss-vocab build" in proc.stderr


def test_orbslam3_outputs_are_staged_until_every_repeat_is_done(
    synthetic_sequence, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A repeat that fails leaves the earlier run in the folder as it was (its log is kept
    beside it); a complete run replaces it with a manifest that lists every file."""
    pytest.importorskip("pyorbslam3")
    from uss_slam.slam_eval.scoring.run_folder import verify_run
    from uss_slam.slam_eval.systems.orbslam3 import system

    seq = synthetic_sequence(preset="static_xyz", frames=12, size=(320, 240))
    vocab = tmp_path / "voc.txt"
    build_from_sequences([seq], vocab, k=6, levels=2, stride=4)
    gt = (seq / "groundtruth.txt").read_text()
    failing: set[int] = set()

    def fake_worker(job, log_path: Path, workdir: Path, index: int) -> dict:
        # ORB-SLAM3 stood in for: a log, a trajectory (the ground truth), the states
        log_path.write_text(f"repeat {index}\n")
        if index in failing:
            raise UssSlamError(f"ORB-SLAM3 exited with code 1 in repeat {index} (log {log_path})")
        Path(job.trajectory).write_text(gt)
        return {"states": ["OK"] * 12, "track_s": 1.0, "load_s": 0.1}

    monkeypatch.setattr(system, "run_worker", fake_worker)

    def run(out: Path, repeats: int) -> dict:
        return run_orbslam3(
            SequenceSpec(str(seq)),
            NoSegmenter(),
            [SemanticFilter()],
            OrbSlam3Config(vocabulary=str(vocab), repeats=repeats, realtime=False),
            EvalConfig(),
            out,
            progress=False,
        )

    out = tmp_path / "run"
    data = run(out, repeats=3)
    assert verify_run(out) == []
    listed = set(json.loads((out / "run.json").read_text())["files"])
    assert {"trajectory.txt", "metrics.json", "orbslam3_settings.yaml",
            "repeats/trajectory_2.txt", "repeats/orbslam3_2.log"} <= listed  # fmt: skip
    assert data["orbslam3"]["settings_file"] == str(out.absolute() / "orbslam3_settings.yaml")
    assert not any(p.name.startswith(".uss-slam-") for p in out.iterdir())
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}

    failing.add(1)  # the second repeat of the next run fails: nothing of it replaces the first
    with pytest.raises(UssSlamError, match="in repeat 1"):
        run(out, repeats=2)
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after.pop(out / "orbslam3_failed.log") == b"repeat 1\n"
    assert after == before and verify_run(out) == []

    failing.clear()  # a run of 2 repeats replaces the run of 3: no third repeat's files stay
    run(out, repeats=2)
    assert verify_run(out) == []
    assert not (out / "repeats" / "trajectory_2.txt").exists()
    assert not (out / "orbslam3_failed.log").exists()


def test_rows_orbslam3_repeats_for_untracked_frames_are_removed(tmp_path: Path, caplog) -> None:
    # ORB-SLAM3 writes a frame it did not track (RECENTLY_LOST) as a copy of the row before,
    # stamp included (measured on walking_xyz seed 1: 23 copies of 3 rows in 300). They are
    # removed with a warning and those frames have no pose; a stamp repeated with another pose
    # is still an error naming the file and line.
    from uss_slam.slam_eval.systems.orbslam3.repeats import read_estimate

    rows = [
        "1.000000 0.0 0.0 0.0 0.0 0.0 0.0 1.0",
        "1.033000 0.1 0.0 0.0 0.0 0.0 0.0 1.0",
        "1.033000 0.1 0.0 0.0 0.0 0.0 0.0 1.0",
        "1.033000 0.1 0.0 0.0 0.0 0.0 0.0 1.0",
        "1.133000 0.2 0.0 0.0 0.0 0.0 0.0 1.0",
    ]
    path = tmp_path / "trajectory_0.txt"
    path.write_text("\n".join(rows) + "\n")
    with caplog.at_level("WARNING"):
        trajectory = read_estimate(path)
    np.testing.assert_allclose(trajectory.stamps, [1.0, 1.033, 1.133])
    assert "2 rows repeated the row before them" in caplog.text
    assert path.read_text().startswith("# 2 rows that repeated the row before")
    assert read_estimate(path).stamps.tolist() == trajectory.stamps.tolist()  # idempotent

    rows[2] = "1.033000 0.5 0.0 0.0 0.0 0.0 0.0 1.0"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(DataFormatError, match=r"trajectory_0.txt:3: duplicate timestamp"):
        read_estimate(path)


def test_empty_filters_with_a_segmenter_are_refused_for_orbslam3() -> None:
    from omegaconf import OmegaConf

    from uss_slam.slam_eval.systems.orbslam3.system import empty_filters_refused

    empty = OmegaConf.create({"filters": []})
    line = empty_filters_refused(empty, ["filters=[]", "segmenter=labels"], "labels")
    assert line is not None and line.startswith("system=orbslam3: filters=[] would still blank")
    assert "segmenter=none" in line
    assert empty_filters_refused(empty, ["filters=[]"], "none") is None  # nothing to blank
    assert empty_filters_refused(empty, ["segmenter=labels"], "labels") is None  # the default
    named = OmegaConf.create({"filters": ["semantic"]})
    assert empty_filters_refused(named, ["filters=[semantic]"], "labels") is None

"""The ``handheld_rpy`` preset: a static scene seen by a hand-held camera swept about its axes
(TUM fr1/rpy-like angular speeds), with a few centimetres of drift, and more motion blur than the
``static_xyz`` control."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from uss_slam.core.tum_io import read_trajectory
from uss_slam.synthetic import PRESETS, SequenceRenderer
from uss_slam.synthetic.motion import CameraMotion
from uss_slam.synthetic.styles import EXPOSURE_TIME

EYE = np.array([0.3, -0.2, 1.3])
TARGET = np.array([2.5, 0.4, 0.8])


def _motion(kind: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over 12 s at 100 Hz: angular speed (deg/s), the peak rate of roll, pitch and yaw about
    the rest orientation's axes (deg/s), and the positions (metres)."""
    motion = CameraMotion(kind, EYE, TARGET, seed)
    poses = np.stack([motion.pose(t) for t in np.arange(0.0, 12.0, 0.01)])
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    angular = np.degrees(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1)) / 0.01
    # rest^T R = R_y(yaw) R_x(pitch) R_z(roll): intrinsic y-x-z Euler angles
    local = np.einsum("ji,njk->nik", motion.base, poses[:, :3, :3])
    yaw, pitch, roll = Rotation.from_matrix(local).as_euler("YXZ", degrees=True).T
    peaks = np.abs(np.diff(np.stack([roll, pitch, yaw], axis=1), axis=0)).max(axis=0) / 0.01
    return angular, peaks, poses[:, :3, 3]


def test_the_preset_is_a_static_scene_with_handheld_motion() -> None:
    preset = PRESETS["handheld_rpy"]
    assert (preset.motion, preset.people) == ("handheld", "frozen")
    for seed in (0, 1, 2):
        angular, peaks, positions = _motion("handheld", seed)
        roll, pitch, yaw = peaks
        assert 25 <= roll <= 45 and 35 <= pitch <= 55 and 50 <= yaw <= 65  # deg/s per axis
        assert 35 <= angular.mean() <= 45  # TUM fr1/rpy: ~50 deg/s on average
        drift = np.abs(positions - EYE).max(axis=0)
        assert (drift <= 0.05).all() and drift.max() >= 0.02  # centimetres, not decimetres
        slow, _, _ = _motion("rpy", seed)
        assert angular.mean() > 3 * slow.mean()  # far faster than walking_rpy's sweep
    seq = SequenceRenderer("handheld_rpy", frames=4, size=(64, 48), seed=0)
    still, later = seq.scene.prims_at(0.0), seq.scene.prims_at(5.0)
    for f in dataclasses.fields(still):  # nothing in the scene moves
        np.testing.assert_array_equal(getattr(still, f.name), getattr(later, f.name))


def test_handheld_frames_blur_more_than_the_control(synthetic_sequence) -> None:
    """Mean image motion during the exposure (the blur length), handheld vs static_xyz."""

    def blur(preset: str) -> float:
        seq = SequenceRenderer(preset, frames=60, size=(80, 60), seed=0)
        lengths = []
        for i in range(0, 60, 6):
            t = seq.time(float(seq.stamps[i]))
            pose = seq.motion.pose(t)
            depth = seq.renderer.render(
                pose, seq.scene.room, seq.scene.prims_at(t), seq.bank, seq.lighting
            ).depth
            flow = seq.renderer.flow(depth, pose, seq.motion.pose(t - EXPOSURE_TIME / 2))
            lengths.append(float(np.linalg.norm(flow, axis=2).mean()))
        return float(np.mean(lengths))

    assert blur("handheld_rpy") > 5 * blur("static_xyz")
    path = synthetic_sequence(preset="handheld_rpy", frames=6, size=(96, 72), seed=1)
    gt = read_trajectory(path / "groundtruth.txt")
    motion = SequenceRenderer("handheld_rpy", frames=6, size=(96, 72), seed=1)
    np.testing.assert_allclose(gt.positions[10], motion.pose(gt.stamps[10])[:3, 3], atol=1e-4)
    assert "handheld_rpy" in (path / "synthetic.yaml").read_text()


def test_kinect_timing_skews_the_rows_and_takes_the_depth_at_its_stamp() -> None:
    """``timing=kinect`` (handheld_rpy's default): the colour rows are read out over 30 ms, so
    the top and bottom rows see the scene moved in opposite directions against a global
    shutter while the middle row does not, the labels with them; the depth image is the
    scene at its own stamp. ``global`` is what the other presets render."""
    import pytest

    from uss_slam.synthetic.output import SynthArgumentError
    from uss_slam.synthetic.sequence import READOUT

    assert PRESETS["handheld_rpy"].timing == "kinect"
    hand = ("handheld_rpy", "handheld_fast")
    assert {p.timing for n, p in PRESETS.items() if n not in hand} == {"global"}
    size = (320, 240)
    plain = SequenceRenderer("handheld_rpy", 40, size, seed=0, timing="global")
    kinect = SequenceRenderer("handheld_rpy", 40, size, seed=0)
    assert kinect.timing == "kinect" and READOUT == 0.03
    a, b = plain.frame(20), kinect.frame(20)
    assert np.array_equal(a.clean_depth, b.clean_depth)  # the same instant is rendered
    # the middle row is read at the stamp: it matches the global shutter; the top and bottom
    # rows were read 15 ms before and after it, while the camera turned
    grey_a, grey_b = a.rgb.mean(-1), b.rgb.mean(-1)
    band = {name: np.abs(grey_a[rows] - grey_b[rows]).mean()
            for name, rows in (("top", slice(0, 30)), ("middle", slice(105, 135)),
                               ("bottom", slice(210, 240)))}  # fmt: skip
    assert band["middle"] < 1.5 and min(band["top"], band["bottom"]) > 2 * band["middle"], band
    assert (a.labels != b.labels).mean() > 0.005  # the labels are skewed with the colour
    depth_changed = (a.depth > 0) & (b.depth > 0) & (np.abs(a.depth.astype(int) - b.depth) > 100)
    assert depth_changed.mean() > 0.005  # edges moved by the 3-12 ms to the depth stamp
    # each half alone: the skew without the depth's own instant, and the other way round
    rolling = SequenceRenderer("handheld_rpy", 40, size, seed=0, timing="rolling").frame(20)
    misregistered = SequenceRenderer("handheld_rpy", 40, size, 0, timing="misregistered").frame(20)
    assert np.array_equal(rolling.rgb, b.rgb) and np.array_equal(rolling.depth, a.depth)
    assert np.array_equal(misregistered.rgb, a.rgb) and np.array_equal(misregistered.depth, b.depth)
    with pytest.raises(SynthArgumentError, match="unknown timing 'slow'; choose one of global"):
        SequenceRenderer("handheld_rpy", 4, size, timing="slow")


def test_the_fast_preset_is_the_handheld_path_four_times_faster() -> None:
    """``handheld_fast``: ``handheld_rpy``'s poses (same seed) at a quarter of the time, so up to
    ~300 deg/s, and the same static scene."""
    preset = PRESETS["handheld_fast"]
    assert (preset.motion, preset.people, preset.timing) == ("handheld_fast", "frozen", "kinect")
    for seed in (0, 1, 2):
        slow = CameraMotion("handheld", EYE, TARGET, seed)
        fast = CameraMotion("handheld_fast", EYE, TARGET, seed)
        for t in (0.0, 0.37, 2.5):
            np.testing.assert_allclose(fast.pose(t), slow.pose(4.0 * t), atol=1e-12)
        angular, _, _ = _motion("handheld_fast", seed)
        assert 250 <= angular.max() <= 340 and 140 <= angular.mean() <= 170  # deg/s

"""Local mapping: bundle adjustment on GTSAM (free / fixed keyframes, outliers, noise models),
keyframe culling, the options and the pipeline with and without it."""

from __future__ import annotations

import json
from pathlib import Path

import gtsam
import numpy as np
import pytest
from shared_helpers import compose_slam_eval, slam_run_config

from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import TUM_CAMERAS, Trajectory, read_trajectory
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import Features, OrbConfig, OrbExtractor
from uss_slam.slam_eval.geometry import from_rvec, invert
from uss_slam.slam_eval.map.slam_map import SlamMap
from uss_slam.slam_eval.mapping.local_mapping import (
    LocalMapping,
    LocalMappingConfig,
    depth_noise_of,
)
from uss_slam.slam_eval.optim.local_ba import BundleAdjuster, point_keys, pose_key, pose_keys
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.tracker import Tracker, TrackerConfig
from uss_slam.synthetic.styles import DEPTH_NOISE_K

CAM = TUM_CAMERAS["fr3"].scaled(640, 480)
EX = OrbExtractor(OrbConfig(), CAM)
BF = CAM.fx * TrackerConfig().virtual_baseline


def _observe(world: np.ndarray, pose_wc: np.ndarray, rng, levels: np.ndarray | None = None):
    """Keypoints of ``world`` points seen from ``pose_wc``: pixel noise 0.7 × the level's scale,
    Kinect-like depth noise 0.0019 z²; returns ``(features, visible)``."""
    cam = (world - pose_wc[:3, 3]) @ pose_wc[:3, :3]
    z = cam[:, 2]
    k = CAM.matrix
    uv = cam[:, :2] / z[:, None] * [k[0, 0], k[1, 1]] + [k[0, 2], k[1, 2]]
    n = len(world)
    level = rng.integers(0, 3, n) if levels is None else levels
    uv = uv + rng.normal(0, 0.7, (n, 2)) * (1.2**level)[:, None]
    zn = z + rng.normal(0, 1, n) * 0.0019 * z**2
    visible = (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480) & (z > 0.1)
    zn = np.where(visible, zn, 0.0).astype(np.float32)
    features = Features(
        uv.astype(np.float32),
        uv,
        level.astype(np.int32),
        np.zeros(n, np.float32),
        np.ones(n, np.float32),
        np.zeros((n, 32), np.uint8),
        zn,
        EX.backproject(uv, zn),
    )
    return features, visible


def _drifted_map(seed: int = 0, keyframes: int = 6, points: int = 800):
    """Keyframe 0 creates every point from its depth; keyframes 1.. observe them all, at poses
    off the truth by ~1 cm and ~0.2 degrees. Returns ``(map, true poses)``."""
    rng = np.random.default_rng(seed)
    world = rng.uniform([-1.5, -1.0, 1.5], [1.5, 1.0, 3.5], (points, 3))
    truth = [
        from_rvec(np.array([0.0, 0.02 * i, 0.0]), np.array([0.06 * i, 0.01 * i, 0.0]))
        for i in range(keyframes)
    ]
    slam_map = SlamMap(1.2, 8)
    first = None
    for i, pose in enumerate(truth):
        features, visible = _observe(world, pose, rng)
        none = np.zeros(points, bool)
        if i == 0:
            first = slam_map.add_keyframe(
                0, 0.0, pose, features, np.full(points, -1), none, visible
            )
            continue
        drift = from_rvec(rng.normal(0, 0.003, 3), rng.normal(0, 0.01, 3))
        ids = np.where(visible, first.point_ids, -1)
        slam_map.add_keyframe(i, float(i), pose @ drift, features, ids, none, none)
    return slam_map, truth


def _errors_mm(slam_map: SlamMap, truth: list[np.ndarray]) -> np.ndarray:
    return np.array(
        [
            1000 * np.linalg.norm((invert(t) @ kf.pose_wc)[:3, 3])
            for kf, t in zip(slam_map.keyframes, truth, strict=False)
        ]
    )


def _adjuster(depth_noise: float = 0.0) -> BundleAdjuster:  # ORB-SLAM2's model
    return BundleAdjuster(CAM.matrix, BF, EX.sigma2, depth_noise)


@pytest.mark.parametrize("depth_noise", [0.0019, 0.0])
def test_local_ba_pulls_drifted_keyframes_back(depth_noise: float) -> None:
    slam_map, truth = _drifted_map()
    before = _errors_mm(slam_map, truth)
    assert before[0] == 0 and before[1:].min() > 4 and before.max() > 15
    mapping = LocalMapping(LocalMappingConfig(culling=False), _adjuster(depth_noise))
    adjustment, culled = mapping.process(slam_map, 5)
    after = _errors_mm(slam_map, truth)
    assert adjustment.free.tolist() == [1, 2, 3, 4, 5] and adjustment.fixed.tolist() == [0]
    assert culled == []
    np.testing.assert_array_equal(slam_map.keyframes[0].pose_wc, truth[0])  # the gauge
    assert after.max() < 3.0, after
    assert adjustment.error[1] < adjustment.error[0] / 5
    assert mapping.stats.runs == 1 and mapping.stats.as_dict()["mean_free_keyframes"] == 5


def test_local_ba_again_with_every_point_taken_out_changes_nothing() -> None:
    """A late mask can mark every point a keyframe's neighbours see as bad: the local BA run
    again around it then has nothing to adjust, and leaves the map as it was."""
    slam_map, _ = _drifted_map()
    slam_map.points.bad.view[:] = True
    poses = [kf.pose_wc.copy() for kf in slam_map.keyframes]
    mapping = LocalMapping(LocalMappingConfig(culling=False), _adjuster())
    adjustment = mapping.readjust(slam_map, 5)
    assert adjustment.free.size == adjustment.points.size == adjustment.observations == 0
    for kf, pose in zip(slam_map.keyframes, poses, strict=True):
        np.testing.assert_array_equal(kf.pose_wc, pose)
    assert mapping.stats.readjusted == 1


def test_keyframes_that_are_not_covisible_stay_fixed() -> None:
    slam_map, truth = _drifted_map(keyframes=5)
    rng = np.random.default_rng(3)
    # A keyframe that sees only 10 of the points: not covisible with keyframe 4 (15 needed).
    world_ids = slam_map.keyframes[0].point_ids
    features, visible = _observe(slam_map.points.position.view[world_ids], truth[2], rng)
    ids = np.where(visible, world_ids, -1)
    ids[np.flatnonzero(ids >= 0)[10:]] = -1
    far = slam_map.add_keyframe(5, 5.0, truth[2] @ from_rvec(np.zeros(3), np.array([0.02, 0, 0])),
                                features, ids, np.zeros(len(ids), bool), np.zeros(len(ids), bool))  # fmt: skip
    pose = far.pose_wc.copy()
    mapping = LocalMapping(LocalMappingConfig(culling=False), _adjuster())
    assert mapping.local_keyframes(slam_map, 4).tolist() == [0, 1, 2, 3, 4]
    adjustment, _ = mapping.process(slam_map, 4)
    assert adjustment.fixed.tolist() == [0, 5]
    np.testing.assert_array_equal(far.pose_wc, pose)
    # Capped: only the 2 most covisible keyframes besides the new one are free.
    capped = LocalMapping(LocalMappingConfig(culling=False, max_keyframes=2), _adjuster())
    assert len(capped.local_keyframes(slam_map, 4)) == 3


def test_a_doubted_keyframe_is_adjusted_alone_and_moves_no_other() -> None:
    """slam.local_ba_params.doubt_inliers: a keyframe tracked with fewer map-point inliers is
    freed alone; the map (the other keyframes fixed) corrects its pose, and no other moves."""
    slam_map, truth = _drifted_map()
    others = [kf.pose_wc.copy() for kf in slam_map.keyframes[:5]]
    slam_map.keyframes[5].inliers = 40
    mapping = LocalMapping(LocalMappingConfig(culling=False, doubt_inliers=50), _adjuster())
    assert mapping.doubted(slam_map, 5) and mapping.local_keyframes(slam_map, 5).tolist() == [5]
    before = _errors_mm(slam_map, truth)[5]
    adjustment, _ = mapping.process(slam_map, 5)
    assert adjustment.free.tolist() == [5] and adjustment.fixed.tolist() == [0, 1, 2, 3, 4]
    for kf, pose in zip(slam_map.keyframes, others, strict=False):
        np.testing.assert_array_equal(kf.pose_wc, pose)
    assert _errors_mm(slam_map, truth)[5] < before
    slam_map.keyframes[5].inliers = 50  # enough: adjusted with its covisible keyframes
    assert not mapping.doubted(slam_map, 5) and len(mapping.local_keyframes(slam_map, 5)) > 1
    off = LocalMapping(LocalMappingConfig(culling=False), _adjuster())  # 0 = off
    slam_map.keyframes[5].inliers = 1
    assert not off.doubted(slam_map, 5)


def test_outlier_observations_are_erased() -> None:
    slam_map, truth = _drifted_map()
    kf = slam_map.keyframes[3]
    observed = np.flatnonzero(kf.point_ids >= 0)
    bad = observed[::25][:20]
    kf.features.uv[bad, 0] += 25.0  # 25 px off: far beyond the chi2 bound
    bad_points = kf.point_ids[bad].copy()
    seen_by = slam_map.points.observations.view[bad_points].copy()
    others = kf.point_ids[kf.point_ids >= 0].size - len(bad)
    adjustment, _ = LocalMapping(LocalMappingConfig(culling=False), _adjuster()).process(
        slam_map, 5
    )
    assert (kf.point_ids[bad] == -1).all()
    assert adjustment.outliers >= len(bad)
    assert kf.point_ids[kf.point_ids >= 0].size >= others - 0.02 * others
    # Each of those points lost that observation; none of them is left with a single keyframe.
    after = slam_map.points.observations.view[bad_points]
    assert (after <= seen_by - 1).all() and (after >= 2).all()
    assert not slam_map.points.bad.view[bad_points].any()
    assert _errors_mm(slam_map, truth).max() < 3.0


def test_redundant_keyframes_are_culled() -> None:
    """Five keyframes see the same points at level 0; going through keyframe 4's covisible ones
    in order, 1 is redundant (0, 2, 3, 4 see its points), then 2 (0, 3, 4), then 3 is not."""
    rng = np.random.default_rng(1)
    world = rng.uniform([-1, -1, 2], [1, 1, 3], (300, 3))
    slam_map = SlamMap(1.2, 8)
    first = None
    for i in range(5):
        pose = from_rvec(np.zeros(3), np.array([0.01 * i, 0, 0]))
        features, visible = _observe(world, pose, rng, levels=np.zeros(300, np.int64))
        ids = np.full(300, -1) if first is None else np.where(visible, first.point_ids, -1)
        kf = slam_map.add_keyframe(i, float(i), pose, features, ids, np.zeros(300, bool),
                                   visible if first is None else np.zeros(300, bool))  # fmt: skip
        first = first or kf
    assert [kf.parent for kf in slam_map.keyframes] == [None, 0, 0, 0, 0]
    pose_1 = slam_map.keyframes[1].pose_wc.copy()
    mapping = LocalMapping(LocalMappingConfig(), _adjuster())
    assert mapping.cull(slam_map, 4) == [1, 2]
    for k in (1, 2):
        kf = slam_map.keyframes[k]
        assert kf.bad and (kf.point_ids == -1).all()
    shared = slam_map.covisibility(first.point_ids[first.point_ids >= 0])
    assert shared[1] == shared[2] == 0 and shared[[0, 3, 4]].min() > 280
    # A culled keyframe keeps its pose relative to its parent, even when the parent moves.
    np.testing.assert_allclose(slam_map.pose_wc(1), pose_1, atol=1e-12)
    shift = from_rvec(np.zeros(3), np.array([0.0, 0.1, 0.0]))
    slam_map.keyframes[0].pose_wc = shift @ slam_map.keyframes[0].pose_wc
    np.testing.assert_allclose(slam_map.pose_wc(1), shift @ pose_1, atol=1e-12)
    with pytest.raises(ValueError, match="cannot be culled"):
        slam_map.cull_keyframe(1)


def test_a_chain_of_culled_keyframes_keeps_its_poses() -> None:
    """Keyframe 2 (parent 1) is culled, then its parent 1: 2's pose stays where it was, since it
    is relative to 1, whose own pose is relative to 0. Handing the culled 2 to 0 with its pose
    relative to 1 moved it by 1's offset from 0 (on walking_xyz seed 1 with ground-truth masks
    a culled keyframe jumped from 3.5 to 150 mm off, and the frames tracked on it with it)."""
    rng = np.random.default_rng(3)
    world = rng.uniform([-1, -1, 2], [1, 1, 3], (100, 3))
    slam_map = SlamMap(1.2, 8)
    first = None
    for i in range(4):
        pose = from_rvec(np.array([0, 0.05 * i, 0]), np.array([0.2 * i, 0.05 * i, 0]))
        features, visible = _observe(world, pose, rng, levels=np.zeros(100, np.int64))
        ids = np.full(100, -1) if first is None else np.where(visible, first.point_ids, -1)
        kf = slam_map.add_keyframe(i, float(i), pose, features, ids, np.zeros(100, bool),
                                   visible if first is None else np.zeros(100, bool))  # fmt: skip
        first = first or kf
    for k in (1, 2, 3):
        slam_map.keyframes[k].parent = k - 1  # a chain 0 <- 1 <- 2 <- 3
    before = [slam_map.pose_wc(k).copy() for k in range(4)]
    slam_map.cull_keyframe(2)
    assert slam_map.keyframes[3].parent == 1  # a good child goes to the grandparent
    slam_map.cull_keyframe(1)
    assert [kf.parent for kf in slam_map.keyframes] == [None, 0, 1, 0]
    for k in range(4):
        np.testing.assert_allclose(slam_map.pose_wc(k), before[k], atol=1e-12)
    shift = from_rvec(np.array([0, 0, 0.1]), np.array([0.0, 0.1, 0.0]))
    slam_map.keyframes[0].pose_wc = shift @ slam_map.keyframes[0].pose_wc
    for k in (1, 2):  # the culled ones move with the good keyframe their chain ends in
        np.testing.assert_allclose(slam_map.pose_wc(k), shift @ before[k], atol=1e-12)


def test_coarser_observations_do_not_make_a_keyframe_redundant() -> None:
    rng = np.random.default_rng(2)
    world = rng.uniform([-1, -1, 2], [1, 1, 3], (200, 3))
    slam_map = SlamMap(1.2, 8)
    first = None
    for i in range(5):
        level = np.zeros(200, np.int64) if i < 2 else np.full(200, 3)
        features, visible = _observe(world, np.eye(4), rng, levels=level)
        ids = np.full(200, -1) if first is None else np.where(visible, first.point_ids, -1)
        kf = slam_map.add_keyframe(i, float(i), np.eye(4), features, ids, np.zeros(200, bool),
                                   visible if first is None else np.zeros(200, bool))  # fmt: skip
        first = first or kf
    mapping = LocalMapping(LocalMappingConfig(), _adjuster())
    # Keyframe 1 sees the points at level 0; the others but keyframe 0 at level 3 (> 0 + 1).
    assert not mapping.redundant(slam_map, 1)
    assert mapping.redundant(slam_map, 2)  # level 3: 0, 1, 3, 4 all count


def test_local_mapping_options_are_checked() -> None:
    with pytest.raises(ValueError, match="covisibility: expected an integer >= 1, got 0"):
        LocalMappingConfig(covisibility=0)
    with pytest.raises(ValueError, match=r"redundancy: expected a number > 0 and <= 1, got 1.5"):
        LocalMappingConfig(redundancy=1.5)
    with pytest.raises(ValueError, match="depth_noise: expected a number >= 0 or null"):
        LocalMappingConfig(depth_noise=-1.0)
    defaults = compose_slam_eval(["sequence.path=/x"])
    assert defaults.slam.local_ba is True and defaults.slam.loop_closing is True  # the back end on
    cfg = compose_slam_eval(
        ["sequence.path=/x", "slam.loop_closing=false", "slam.local_ba_params.redundancy=2"]
    )
    assert cfg.slam.local_ba is True and cfg.slam.loop_closing is False
    with pytest.raises(
        UssSlamError, match=r"slam\.local_ba_params\.redundancy: expected a number > 0 and <= 1"
    ):
        run(cfg)


def test_depth_noise_is_the_settings_else_the_cameras_else_orbslam2s() -> None:
    assert depth_noise_of(LocalMappingConfig(depth_noise=0.005), 0.0019) == (
        0.005, "slam.local_ba_params.depth_noise"
    )  # fmt: skip
    assert depth_noise_of(LocalMappingConfig(depth_noise=0.0), 0.0019)[0] == 0.0
    assert depth_noise_of(LocalMappingConfig(), 0.0019) == (0.0019, "the camera's intrinsics.yaml")
    k, source = depth_noise_of(LocalMappingConfig(), None)  # a real Kinect: TUM's cameras
    assert k == 0.0 and source.startswith("ORB-SLAM2's model")


@pytest.mark.parametrize(
    ("overrides", "k", "source"),
    [
        # TUM's fr3 calibration, as for a real recording: no declared noise
        (["sequence.camera=fr3"], 0.0, "ORB-SLAM2's model (the camera declares no depth noise)"),
        (["slam.local_ba_params.depth_noise=0.004"], 0.004, "slam.local_ba_params.depth_noise"),
    ],
)
def test_local_ba_reports_the_depth_noise_it_models(
    synthetic_sequence, tmp_path: Path, overrides: list[str], k: float, source: str
) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=30)
    cfg = slam_run_config(path, tmp_path / "run", "slam.local_ba=true", *overrides)
    ba = run(cfg)["local_ba"]
    assert (ba["depth_noise"], ba["depth_noise_from"]) == (k, source)


def _pipeline(path: Path, **kwargs) -> SlamPipeline:
    return SlamPipeline(
        TumSequence(path), NoSegmenter(), build_filters([]), progress=False, **kwargs
    )


def test_without_back_end_the_trajectory_is_the_trackers(synthetic_sequence) -> None:
    """local_ba=false, loop_closing=false: every pose is the tracker's own estimate of the frame,
    bit for bit (the harness as it was before the back end)."""
    path = synthetic_sequence(preset="static_xyz", frames=30)
    result = _pipeline(path, local_ba=False, loop_closing=False).run()
    assert result.local_ba is None and result.loop_closures == [] and not result.loop_closing
    assert "local_ba" not in result.timing_ms and "loop_closing" not in result.timing_ms
    seq = TumSequence(path)
    ex = OrbExtractor(OrbConfig(), seq.camera)
    tracker = Tracker(TrackerConfig(), ex)
    stamps, poses = [], []
    for i in range(len(seq)):
        frame = seq.load(i)
        features = ex(frame.gray, frame.depth)
        dynamic = np.zeros(len(features), bool)
        r = tracker.track(i, frame.stamp, features, dynamic)
        tracker.finish_frame(i, frame.stamp, r, features, dynamic)
        stamps.append(frame.stamp)
        poses.append(r.pose_wc)
    expected = Trajectory.from_matrices(stamps, np.stack(poses))
    np.testing.assert_array_equal(result.trajectory.positions, expected.positions)
    np.testing.assert_array_equal(result.trajectory.quaternions, expected.quaternions)


def test_local_ba_runs_after_every_keyframe(synthetic_sequence, tmp_path: Path) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=30)
    out = tmp_path / "run"
    # ORB-SLAM2's keyframe rule makes one keyframe in these 30 slow frames (every point is still
    # tracked); asking for more close points than a frame holds makes its close-point rule
    # (c2: too few close points tracked) hold on most frames: 22 keyframes.
    cfg = slam_run_config(
        path, out, "slam.loop_closing=false", "slam.tracker.min_close_tracked=1000"
    )
    data = run(cfg)
    ba = data["local_ba"]
    assert ba["runs"] == data["keyframes"] - 1 >= 1
    assert set(ba) == {"runs", "wall_ms", "keyframes_culled", "observations_erased",
                       "mean_free_keyframes", "mean_points", "depth_noise",
                       "depth_noise_from", "keyframes_deferred", "keyframes_skipped",
                       "readjusted"}  # fmt: skip
    assert ba["keyframes_deferred"] == ba["keyframes_skipped"] == 0  # min_interval_s = 0
    assert ba["readjusted"] == 0  # masks on every frame are never late
    # the synthetic target style declares its depth noise, and local BA models it
    assert ba["depth_noise"] == DEPTH_NOISE_K
    assert ba["depth_noise_from"] == "the camera's intrinsics.yaml"
    assert data["loop_closing"] is False and data["loop_closures"] == 0
    assert data["timing_ms"]["local_ba"] > 0 and data["frames_tracked"] == 30
    assert data["ate"]["rmse"] < 0.02
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["settings"]["slam"]["local_ba"] is True
    report = (out / "report.md").read_text()
    assert (
        f"Local bundle adjustment: {ba['runs']} runs" in report and "Loop closing: off." in report
    )
    assert "Depth noise model: σ_z = 0.0019·z², from the camera's intrinsics.yaml." in report
    off = _pipeline(path).run()
    estimate = read_trajectory(out / "trajectory.txt")
    assert len(estimate) == len(off.trajectory) == 30
    assert not np.array_equal(estimate.positions, off.trajectory.positions)
    seq = TumSequence(path)
    assert ate(seq.groundtruth, estimate).stats.rmse < 0.02


def test_pose_and_point_keys_are_gtsams_symbols() -> None:
    ids = np.array([0, 1, 7, 123_456, 2**40 + 3, 2**56 - 1])
    assert pose_keys(ids) == [gtsam.symbol("x", int(i)) for i in ids]
    assert point_keys(ids) == [gtsam.symbol("l", int(i)) for i in ids]
    assert pose_keys(ids[2:3]) == [pose_key(7)] and point_keys(np.array([], int)) == []
    for bad in (-1, 2**56):
        with pytest.raises(ValueError, match=r"GTSAM symbol 'l': expected ids in \[0, 2\^56\)"):
            point_keys(np.array([3, bad]))


def _plain_factors(adjuster: BundleAdjuster, obs, rows: np.ndarray, robust: bool):
    """The factor graph as one loop over the observations would build it: the reference."""
    graph = gtsam.NonlinearFactorGraph()
    for r in rows:
        u, v, ur = obs.meas[r]
        level = int(obs.level[r])
        keys = gtsam.symbol("x", int(obs.keyframe[r])), gtsam.symbol("l", int(obs.point[r]))
        if obs.stereo[r]:
            noise = adjuster.noise(True, level, robust)
            cal = adjuster.stereo_calibration
            graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(u, ur, v), noise, *keys, cal))
        else:
            noise = adjuster.noise(False, level, robust)
            cal = adjuster.mono_calibration
            graph.add(gtsam.GenericProjectionFactorCal3_S2(np.array([u, v]), noise, *keys, cal))
    return graph


@pytest.mark.parametrize("depth_noise", [0.0, 0.0019])
@pytest.mark.parametrize("robust", [True, False])
def test_factor_graph_is_the_plain_construction(depth_noise: float, robust: bool) -> None:
    """Built at once, the graph has the same factors in the same order as one built factor by
    factor, and optimises to bit-identical values."""
    slam_map, _ = _drifted_map(keyframes=4, points=300)
    adjuster = _adjuster(depth_noise)
    obs = adjuster._gather(slam_map, np.arange(slam_map.n_points))
    rng = np.random.default_rng(5)
    obs.stereo[rng.random(len(obs.point)) < 0.3] = False  # a mix of monocular observations
    obs.level[:] = rng.integers(0, 8, len(obs.point))
    rows = np.flatnonzero(rng.random(len(obs.point)) < 0.8)
    graph = adjuster._factors(obs, rows, robust)
    plain = _plain_factors(adjuster, obs, rows, robust)
    assert graph.size() == plain.size() == len(rows)
    assert 0 < obs.stereo[rows].sum() < len(rows)
    base = gtsam.noiseModel.Gaussian if depth_noise else gtsam.noiseModel.Isotropic
    for i in range(graph.size()):
        ours, ref = graph.at(i), plain.at(i)
        assert type(ours) is type(ref) and ours.keys() == ref.keys()
        if obs.stereo[rows[i]]:
            np.testing.assert_array_equal(ours.measured().vector(), ref.measured().vector())
        else:
            np.testing.assert_array_equal(ours.measured(), ref.measured())
        noise, ref_noise = ours.noiseModel(), ref.noiseModel()
        assert type(noise) is type(ref_noise)
        assert isinstance(noise, gtsam.noiseModel.Robust if robust else base)
        if robust:
            noise, ref_noise = noise.noise(), ref_noise.noise()
        assert noise.covariance().tobytes() == ref_noise.covariance().tobytes()
        assert ours.serialize() == ref.serialize()  # measurement, keys, noise, calibration
    values = gtsam.Values()
    for k in range(len(slam_map.keyframes)):
        values.insert(gtsam.symbol("x", k), gtsam.Pose3(slam_map.keyframes[k].pose_wc))
    positions = slam_map.points.position.view
    for p in np.unique(obs.point[rows]):
        values.insert(gtsam.symbol("l", int(p)), positions[p])
    for g in (graph, plain):
        g.add(gtsam.PriorFactorPose3(gtsam.symbol("x", 0), values.atPose3(gtsam.symbol("x", 0)),
                                     adjuster.fixed_noise))  # fmt: skip
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(3)
    ours = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    ref = gtsam.LevenbergMarquardtOptimizer(plain, values, params).optimize()
    assert graph.error(ours) == plain.error(ref) < plain.error(values)
    for k in range(len(slam_map.keyframes)):
        key = gtsam.symbol("x", k)
        assert ours.atPose3(key).matrix().tobytes() == ref.atPose3(key).matrix().tobytes()
    points = gtsam.utilities.extractPoint3(ours)
    assert points.tobytes() == gtsam.utilities.extractPoint3(ref).tobytes()

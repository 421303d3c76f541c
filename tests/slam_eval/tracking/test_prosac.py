"""PROSAC sampling of the tracker's PnP (``slam.tracker.sampler=prosac``): OpenCV's USAC with the
matches in order of descriptor distance, the option's checks, and tracking with it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from shared_helpers import compose_slam_eval

from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.filters.build import build_filters
from uss_slam.slam_eval.frontend.orb import Features, OrbConfig, OrbExtractor
from uss_slam.slam_eval.geometry import from_rvec, invert
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.scoring.metrics import ate
from uss_slam.slam_eval.segmenters.base import NoSegmenter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.harness import SlamPipeline
from uss_slam.slam_eval.tracking.tracker import SAMPLERS, Tracker, TrackerConfig

CAM = TUM_CAMERAS["fr3"].scaled(640, 480)


def _matches(seed: int = 0, n: int = 200, outliers: float = 0.4):
    """Map points and a frame seeing them from ``pose_cw``; a fraction of the matches are wrong
    (random pixels) and have the larger descriptor distances. Returns ``(world, features,
    keypoints, distances, pose_cw, wrong)`` in a shuffled order."""
    rng = np.random.default_rng(seed)
    pose_cw = from_rvec(np.array([0.02, -0.05, 0.01]), np.array([0.1, -0.05, 0.2]))
    world = rng.uniform([-1.5, -1.0, 1.5], [1.5, 1.0, 3.5], (n, 3))
    cam = world @ pose_cw[:3, :3].T + pose_cw[:3, 3]
    k = CAM.matrix
    uv = cam[:, :2] / cam[:, 2:] * [k[0, 0], k[1, 1]] + [k[0, 2], k[1, 2]]
    uv += rng.normal(0, 0.5, uv.shape)
    wrong = rng.random(n) < outliers
    uv[wrong] = rng.uniform([0, 0], [640, 480], (int(wrong.sum()), 2))
    distance = np.where(wrong, rng.integers(40, 64, n), rng.integers(0, 50, n)).astype(np.int32)
    depth = np.where(wrong, 0.0, cam[:, 2]).astype(np.float32)
    ex = OrbExtractor(OrbConfig(), CAM)
    features = Features(
        uv.astype(np.float32),
        uv,
        np.zeros(n, np.int32),
        np.zeros(n, np.float32),
        np.ones(n, np.float32),
        np.zeros((n, 32), np.uint8),
        depth,
        ex.backproject(uv, depth),
    )
    return world, features, np.arange(n), distance, pose_cw, wrong, ex


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_pose_from_matches_with_each_sampler(sampler: str, monkeypatch) -> None:
    world, features, kp, distance, pose_cw, wrong, ex = _matches()
    calls = []
    original = cv2.solvePnPRansac

    def spy(*args, **kwargs):
        calls.append((np.asarray(args[1]).reshape(-1, 2).copy(), kwargs))
        return original(*args, **kwargs)

    monkeypatch.setattr(cv2, "solvePnPRansac", spy)
    tracker = Tracker(TrackerConfig(sampler=sampler), ex)
    found = tracker.sampler.pnp_global(world, features, kp, distance)
    assert found is not None
    estimate, inliers = found
    error = invert(pose_cw) @ estimate
    assert np.linalg.norm(error[:3, 3]) < 0.005
    # The inlier mask is in the caller's order: the wrong matches are out, nearly all others in.
    assert not inliers[wrong].any() and inliers[~wrong].mean() > 0.95
    (image_points, options), *_ = calls
    if sampler == "prosac":
        params = options["params"]
        assert params.sampler == cv2.SAMPLING_PROSAC and params.maxIterations == 300
        assert params.loMethod == cv2.LOCAL_OPTIM_NULL and params.threshold == 3.0
        order = np.argsort(distance, kind="stable")
        np.testing.assert_array_equal(image_points, features.uv[order])
        assert np.all(np.diff(distance[order]) >= 0)
    else:
        assert options["flags"] == cv2.SOLVEPNP_AP3P and options["iterationsCount"] == 300
        np.testing.assert_array_equal(image_points, features.uv)


def test_sampler_option_is_checked() -> None:
    with pytest.raises(
        ValueError, match="sampler: expected one of 'ransac', 'prosac', got 'lmeds'"
    ):
        TrackerConfig(sampler="lmeds")
    assert TrackerConfig().sampler == "ransac"
    cfg = compose_slam_eval(["sequence.path=/x", "slam.tracker.sampler=lmeds"])
    with pytest.raises(
        UssSlamError, match=r"slam\.tracker\.sampler: expected one of \'ransac\', \'prosac\'"
    ):
        run(cfg)


def test_tracking_with_prosac(synthetic_sequence) -> None:
    path = synthetic_sequence(preset="static_xyz", frames=30)
    seq = TumSequence(path)
    result = SlamPipeline(
        seq,
        NoSegmenter(),
        build_filters([]),
        tracker=TrackerConfig(sampler="prosac"),
        progress=False,
    ).run()
    assert result.tracked == 30 and result.relocalisations == 0
    assert ate(seq.groundtruth, result.trajectory).stats.rmse < 0.02

"""RGB-D pose-only optimisation: exact recovery, noise, robustness, χ² classification."""

from __future__ import annotations

import cv2
import numpy as np

from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.geometry import invert, project, transform
from uss_slam.slam_eval.optim import pose as pose_module
from uss_slam.slam_eval.optim.pose import (
    CHI2_MONO,
    CHI2_STEREO,
    chi2,
    observations,
    optimise_pose,
)

K = TUM_CAMERAS["fr3"].matrix
BF = 535.4 * 0.075


def _pose(rvec, t) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
    out[:3, 3] = t
    return out


def _scene(seed: int, n: int = 300):
    rng = np.random.default_rng(seed)
    pose_cw = _pose([0.05, -0.1, 0.02], [0.1, -0.05, 0.2])
    cam = np.column_stack(
        [rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n), rng.uniform(1.0, 4.0, n)]
    )
    world = transform(invert(pose_cw), cam)
    uv = project(K, cam)
    depth = cam[:, 2].copy()
    depth[rng.random(n) < 0.3] = 0.0  # some keypoints without depth
    return rng, pose_cw, world, uv, depth


def _errors(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = invert(a) @ b
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(d[:3, 3])), float(angle)


def test_exact_observations_recover_the_pose() -> None:
    _, truth, world, uv, depth = _scene(0)
    obs, stereo = observations(uv, depth, BF)
    start = _pose([0.07, -0.12, 0.0], [0.13, -0.02, 0.25])
    est = optimise_pose(K, BF, start, world, obs, stereo, np.ones(len(uv)))
    t_err, r_err = _errors(truth, est)
    assert t_err < 1e-6 and r_err < 1e-5  # micrometres: the convergence tolerance
    e2, front = chi2(K, BF, est, world, obs, stereo, np.ones(len(uv)))
    assert front.all() and e2.max() < 1e-6


def test_noisy_observations_stay_close() -> None:
    rng, truth, world, uv, depth = _scene(1)
    noisy = uv + rng.normal(0, 0.7, uv.shape)
    obs, stereo = observations(noisy, depth, BF)
    est = optimise_pose(K, BF, _pose([0.06, -0.09, 0.03], [0.12, -0.04, 0.18]), world, obs,
                        stereo, np.ones(len(uv)))  # fmt: skip
    t_err, r_err = _errors(truth, est)
    assert t_err < 0.005 and r_err < 0.05


def test_huber_kernel_resists_gross_outliers() -> None:
    rng, truth, world, uv, depth = _scene(2)
    bad = uv.copy()
    wrong = rng.random(len(uv)) < 0.25
    bad[wrong] += rng.uniform(15, 40, (wrong.sum(), 2)) * rng.choice([-1, 1], (wrong.sum(), 2))
    obs, stereo = observations(bad, depth, BF)
    start = _pose([0.06, -0.09, 0.03], [0.12, -0.04, 0.18])
    ones = np.ones(len(uv))
    robust = optimise_pose(K, BF, start, world, obs, stereo, ones, robust=True)
    plain = optimise_pose(K, BF, start, world, obs, stereo, ones, robust=False)
    assert _errors(truth, robust)[0] < 0.3 * _errors(truth, plain)[0]
    # After re-optimising on the χ²-inliers only (what the tracker does), the pose is exact.
    e2, _ = chi2(K, BF, robust, world, obs, stereo, ones)
    inl = e2 < np.where(stereo, CHI2_STEREO, CHI2_MONO)
    assert not inl[wrong].any() and inl[~wrong].all()
    final = optimise_pose(K, BF, robust, world[inl], obs[inl], stereo[inl], ones[inl])
    assert _errors(truth, final)[0] < 1e-6


def test_depth_term_uses_the_virtual_right_coordinate() -> None:
    uv = np.array([[300.0, 200.0], [10.0, 20.0]])
    obs, stereo = observations(uv, np.array([2.0, 0.0]), BF)
    np.testing.assert_allclose(obs[0], [300.0, 200.0, 300.0 - BF / 2.0])
    assert stereo.tolist() == [True, False]
    # A point 10 cm off along the ray costs nothing in (u, v) but shows in u_r.
    world = np.array([[0.0, 0.0, 2.1]])
    o, s = observations(np.array([[K[0, 2], K[1, 2]]]), np.array([2.0]), BF)
    e2, _ = chi2(K, BF, np.eye(4), world, o, s, np.ones(1))
    np.testing.assert_allclose(e2[0], (BF / 2.1 - BF / 2.0) ** 2, rtol=1e-12)


def test_the_solve_is_numpys_bit_for_bit_and_a_singular_system_stops() -> None:
    """Each Gauss-Newton step is ``np.linalg.solve``'s result exactly (the trajectories stay
    the same); a singular normal matrix ends the iterations with the pose reached."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        a = rng.normal(size=(6, 6)) * 10.0 ** rng.uniform(-3, 3, 6)
        h, g = a @ a.T + 1e-9 * np.eye(6), rng.normal(size=6)
        np.testing.assert_array_equal(pose_module._solve(h, g), np.linalg.solve(h, g))
    assert pose_module._solve(np.zeros((6, 6)), np.ones(6)) is None
    _, pose_cw, world, uv, depth = _scene(4)
    obs, stereo = observations(uv, depth, BF)
    none = slice(0, 0)  # no observation: the normal matrix is all zeros
    same = optimise_pose(K, BF, pose_cw, world[none], obs[none], stereo[none], np.ones(0))
    np.testing.assert_array_equal(same, pose_cw)


def test_the_tolerance_stops_the_steps_early() -> None:
    """A step smaller than ``tolerance`` in every component is the last one: a tolerance above
    the first step's size stops after it, as one iteration does; the default goes on."""
    _, truth, world, uv, depth = _scene(0)
    obs, stereo = observations(uv, depth, BF)
    start = _pose([0.07, -0.12, 0.0], [0.13, -0.02, 0.25])  # ~0.06 m and ~0.03 rad off
    ones = np.ones(len(uv))
    one_step = optimise_pose(K, BF, start, world, obs, stereo, ones, iterations=1)
    loose = optimise_pose(K, BF, start, world, obs, stereo, ones, tolerance=1.0)
    default = optimise_pose(K, BF, start, world, obs, stereo, ones)
    assert np.array_equal(loose, one_step)
    assert _errors(truth, default)[0] < 1e-6 < _errors(truth, one_step)[0]
    assert np.array_equal(optimise_pose(K, BF, start, world, obs, stereo, ones, tolerance=1e-7),
                          default)  # fmt: skip

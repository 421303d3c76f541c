"""Pose-only optimisation with RGB-D observations (ORB-SLAM2's ``PoseOptimization``), NumPy.

A keypoint with a depth measurement ``z`` is treated as a stereo observation ``(u, v, u_r)`` with
the virtual right-image coordinate ``u_r = u - bf / z`` (``bf`` = fx × virtual baseline, as
ORB-SLAM2's RGB-D mode); one without depth is a plain ``(u, v)`` observation. The residuals are
weighted by the keypoint level's inverse variance, robustified by a Huber kernel (thresholds
√7.815 and √5.991, the 95% χ² quantiles for 3 and 2 degrees of freedom) and minimised by
Gauss–Newton over a left perturbation of ``T_cw``. Using the depth pins the translation along
the viewing direction and breaks the rotation/translation ambiguity of narrow-field PnP, which
is what makes RGB-D tracking steadier than monocular tracking.
"""

from __future__ import annotations

import cv2
import numpy as np

CHI2_MONO = 5.991
"""95% χ² quantile, 2 degrees of freedom: inlier bound for (u, v) observations."""
CHI2_STEREO = 7.815
"""95% χ² quantile, 3 degrees of freedom: inlier bound for (u, v, u_r) observations."""


def _camera_residuals(k: np.ndarray, bf: float, cam: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """Residuals ``(M, 3)`` of camera points ``cam`` (M, 3) against ``obs`` (predicted −
    observed; u_r column is meaningful only where the observation has one)."""
    z = cam[:, 2]
    inv_z = 1.0 / np.where(np.abs(z) < 1e-9, 1e-9, z)
    u = k[0, 0] * cam[:, 0] * inv_z + k[0, 2]
    v = k[1, 1] * cam[:, 1] * inv_z + k[1, 2]
    return np.stack([u - obs[:, 0], v - obs[:, 1], (u - bf * inv_z) - obs[:, 2]], axis=1)


def _residuals(
    k: np.ndarray, bf: float, pose_cw: np.ndarray, world: np.ndarray, obs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Camera points ``(M, 3)`` and residuals ``(M, 3)`` (:func:`_camera_residuals`)."""
    cam = world @ pose_cw[:3, :3].T + pose_cw[:3, 3]
    return cam, _camera_residuals(k, bf, cam, obs)


def chi2(
    k: np.ndarray,
    bf: float,
    pose_cw: np.ndarray,
    world: np.ndarray,
    obs: np.ndarray,
    stereo: np.ndarray,
    inv_sigma2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-observation weighted squared error ``(M,)`` and the in-front test ``(M,)``."""
    cam, res = _residuals(k, bf, pose_cw, world, obs)
    e2 = res[:, 0] ** 2 + res[:, 1] ** 2 + np.where(stereo, res[:, 2] ** 2, 0.0)
    return e2 * inv_sigma2, cam[:, 2] > 0


def observations(uv: np.ndarray, depth: np.ndarray, bf: float) -> tuple[np.ndarray, np.ndarray]:
    """``(M, 3)`` observations ``(u, v, u_r)`` and the ``(M,)`` has-depth mask."""
    stereo = depth > 0
    ur = np.where(stereo, uv[:, 0] - bf / np.where(stereo, depth, 1.0), 0.0)
    return np.column_stack([uv, ur]), stereo


def optimise_pose(
    k: np.ndarray,
    bf: float,
    pose_cw: np.ndarray,
    world: np.ndarray,
    obs: np.ndarray,
    stereo: np.ndarray,
    inv_sigma2: np.ndarray,
    iterations: int = 10,
    robust: bool = True,
) -> np.ndarray:
    """Gauss–Newton refinement of ``pose_cw`` (4, 4) on the given observations."""
    fx, fy = k[0, 0], k[1, 1]
    delta = np.where(stereo, np.sqrt(CHI2_STEREO), np.sqrt(CHI2_MONO))
    pose = pose_cw.copy()
    for _ in range(iterations):
        cam, res = _residuals(k, bf, pose, world, obs)
        x, y, z = cam[:, 0], cam[:, 1], cam[:, 2]
        inv_z = 1.0 / z
        inv_z2 = inv_z * inv_z
        res[~stereo, 2] = 0.0
        # d(u, v, u_r)/d(camera point)
        jp = np.zeros((len(z), 3, 3))
        jp[:, 0, 0] = fx * inv_z
        jp[:, 0, 2] = -fx * x * inv_z2
        jp[:, 1, 1] = fy * inv_z
        jp[:, 1, 2] = -fy * y * inv_z2
        jp[:, 2, 0] = jp[:, 0, 0]
        jp[:, 2, 2] = np.where(stereo, jp[:, 0, 2] + bf * inv_z2, 0.0)
        # d(camera point)/d(xi) for T <- exp(xi) T, xi = (rho, phi): [I | -[p]x]
        jx = np.zeros((len(z), 3, 6))
        jx[:, 0, 0] = jx[:, 1, 1] = jx[:, 2, 2] = 1.0
        jx[:, 0, 4], jx[:, 0, 5] = z, -y
        jx[:, 1, 3], jx[:, 1, 5] = -z, x
        jx[:, 2, 3], jx[:, 2, 4] = y, -x
        jac = jp @ jx  # (M, 3, 6)
        w = inv_sigma2.copy()
        if robust:
            e = np.sqrt((res**2).sum(axis=1) * inv_sigma2)
            w = w * np.where(e <= delta, 1.0, delta / np.maximum(e, 1e-12))
        flat = jac.reshape(-1, 6)
        weighted = flat * np.repeat(w, 3)[:, None]
        h = weighted.T @ flat
        g = weighted.T @ res.reshape(-1)
        try:
            step = -np.linalg.solve(h, g)
        except np.linalg.LinAlgError:
            break
        update = np.eye(4)
        update[:3, :3] = cv2.Rodrigues(step[3:].reshape(3, 1))[0]
        update[:3, 3] = step[:3]
        pose = update @ pose
        if np.abs(step).max() < 1e-7:  # sub-micrometre / sub-microradian: converged
            break
    return pose


def chi2_per_observation(
    k: np.ndarray,
    bf: float,
    poses_cw: np.ndarray,
    world: np.ndarray,
    obs: np.ndarray,
    stereo: np.ndarray,
    inv_sigma2: np.ndarray,
    disparity_sigma: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`chi2` with one pose per observation: ``poses_cw`` (M, 4, 4), the other arrays as
    there. Returns the weighted squared errors ``(M,)`` and the in-front test ``(M,)`` (what
    ORB-SLAM2's bundle adjustments test after optimising: ``chi2()`` and ``isDepthPositive()``).

    ``disparity_sigma`` > 0 (pixels): the stereo observations' ``u`` and ``u_r`` share the
    keypoint's noise and differ by the disparity ``bf / z``, whose own noise is this sigma, so the
    error is ``(e_u² + e_v²) / σ² + (e_u - e_ur)² / disparity_sigma²`` (the Mahalanobis form of
    that covariance); 0 = ORB-SLAM2's independent ``(u, v, u_r)``."""
    cam = np.einsum("mij,mj->mi", poses_cw[:, :3, :3], world) + poses_cw[:, :3, 3]
    eu, ev, er = _camera_residuals(k, bf, cam, obs).T
    e2 = (eu**2 + ev**2) * inv_sigma2
    # Correlated model: (e_u - e_ur) is the disparity's error.
    extra = (eu - er) ** 2 / disparity_sigma**2 if disparity_sigma > 0 else er**2 * inv_sigma2
    return e2 + np.where(stereo, extra, 0.0), cam[:, 2] > 0

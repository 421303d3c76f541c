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
    """Gauss–Newton refinement of ``pose_cw`` (4, 4) on the given observations.

    Each observation contributes the rows of ``u``, ``v`` and (with depth) ``u_r``; the row of
    a residual ``r`` whose derivative by the camera point ``p = (x, y, z)`` is
    ``(r_x, r_y, r_z)`` has, for a left perturbation ``xi = (rho, phi)`` (``dp/dxi = [I | -[p]x]``),
    the Jacobian ``(r_x, r_y, r_z, y r_z - z r_y, z r_x - x r_z, x r_y - y r_x)``, written out
    per column so that no per-observation matrices are built.
    """
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    world = np.asarray(world, dtype=np.float64)
    wx, wy, wz = world[:, 0], world[:, 1], world[:, 2]
    ou, ov, our = obs[:, 0], obs[:, 1], obs[:, 2]
    has = stereo.astype(np.float64)
    delta2 = np.where(stereo, CHI2_STEREO, CHI2_MONO)
    m = len(world)
    jac = np.zeros((3, m, 6))  # rows u, v, u_r; the constant zeros are never written
    res = np.empty((3, m))
    weight = np.empty((3, m))
    pose = pose_cw.copy()
    for _ in range(iterations):
        r, t = pose[:3, :3], pose[:3, 3]
        x = r[0, 0] * wx + r[0, 1] * wy + r[0, 2] * wz + t[0]
        y = r[1, 0] * wx + r[1, 1] * wy + r[1, 2] * wz + t[1]
        z = r[2, 0] * wx + r[2, 1] * wy + r[2, 2] * wz + t[2]
        inv_z = 1.0 / z
        a = fx * inv_z  # du/dx
        b = -a * x * inv_z  # du/dz
        c = fy * inv_z  # dv/dy
        d = -c * y * inv_z  # dv/dz
        e = b + bf * inv_z * inv_z  # du_r/dz (du_r/dx = a)
        u = a * x + cx
        res[0] = u - ou
        res[1] = c * y + cy - ov
        res[2] = (u - bf * inv_z - our) * has
        w = inv_sigma2
        if robust:
            e2 = (res[0] ** 2 + res[1] ** 2 + res[2] ** 2) * inv_sigma2
            w = inv_sigma2 * np.where(e2 <= delta2, 1.0, np.sqrt(delta2 / np.maximum(e2, 1e-24)))
        az, ay = a * z, a * y
        ju, jv, jr = jac
        ju[:, 0], ju[:, 2], ju[:, 3], ju[:, 4], ju[:, 5] = a, b, y * b, az - x * b, -ay
        jv[:, 1], jv[:, 2], jv[:, 3], jv[:, 4], jv[:, 5] = c, d, y * d - z * c, -x * d, x * c
        jr[:, 0], jr[:, 2], jr[:, 3], jr[:, 4], jr[:, 5] = a, e, y * e, az - x * e, -ay
        weight[0] = w
        weight[1] = w
        weight[2] = w * has
        flat = jac.reshape(-1, 6)
        weighted = flat * weight.reshape(-1, 1)
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

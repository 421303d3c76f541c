"""The observation model that tracking and the back end share (ORB-SLAM2's RGB-D edges).

A keypoint with a depth measurement ``z`` is a stereo observation ``(u, v, u_r)`` with the virtual
right-image coordinate ``u_r = u - bf / z`` (``bf`` = fx × virtual baseline, as ORB-SLAM2's RGB-D
mode); one without depth is a plain ``(u, v)`` observation. Errors are weighted by the keypoint
level's inverse variance and tested against the 95% χ² quantiles (:data:`CHI2_MONO`,
:data:`CHI2_STEREO`). The pose-only optimisation of tracking (:mod:`..optim.pose`) and the
bundle adjustment of the back end (:mod:`..mapping.local_mapping`) both use it.
"""

from __future__ import annotations

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

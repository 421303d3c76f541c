"""Pose-only optimisation with RGB-D observations (ORB-SLAM2's ``PoseOptimization``), NumPy.

The observations are those of the shared model (:mod:`..map.observation`): ``(u, v, u_r)`` with
depth, ``(u, v)`` without. The residuals are weighted by the keypoint level's inverse variance,
robustified by a Huber kernel (thresholds √7.815 and √5.991, the 95% χ² quantiles for 3 and 2
degrees of freedom) and minimised by Gauss–Newton over a left perturbation of ``T_cw``. Using the
depth pins the translation along the viewing direction and breaks the rotation/translation
ambiguity of narrow-field PnP, which is what makes RGB-D tracking steadier than monocular
tracking.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..map.observation import CHI2_MONO, CHI2_STEREO, chi2, observations

try:  # the LU solve np.linalg.solve runs, without its per-call checks and conversions
    from numpy.linalg import _umath_linalg

    _SOLVE1 = _umath_linalg.solve1
except (ImportError, AttributeError):  # pragma: no cover - another NumPy: its public solve
    _SOLVE1 = None

__all__ = ["CHI2_MONO", "CHI2_STEREO", "chi2", "observations", "optimise_pose"]


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
    tolerance: float = 1e-7,
) -> np.ndarray:
    """Gauss–Newton refinement of ``pose_cw`` (4, 4) on the given observations.

    Each observation contributes the rows of ``u``, ``v`` and (with depth) ``u_r``; the row of
    a residual ``r`` whose derivative by the camera point ``p = (x, y, z)`` is
    ``(r_x, r_y, r_z)`` has, for a left perturbation ``xi = (rho, phi)`` (``dp/dxi = [I | -[p]x]``),
    the Jacobian ``(r_x, r_y, r_z, y r_z - z r_y, z r_x - x r_z, x r_y - y r_x)``, written out
    per column so that no per-observation matrices are built.

    The iterations stop early once a step moves the pose by less than ``tolerance`` in every
    component (metres, radians).
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
        step = _solve(h, g)
        if step is None:  # singular
            break
        step = -step
        update = np.eye(4)
        update[:3, :3] = cv2.Rodrigues(step[3:].reshape(3, 1))[0]
        update[:3, 3] = step[:3]
        pose = update @ pose
        if np.abs(step).max() < tolerance:  # converged
            break
    return pose


def _solve(h: np.ndarray, g: np.ndarray) -> np.ndarray | None:
    """``h⁻¹ g`` for a (6, 6) float64 ``h`` and (6,) ``g``, or None where ``h`` is singular:
    ``np.linalg.solve``'s own LAPACK call (the same result bit for bit) without the ~10 µs of
    checks it makes per call, ~30 calls a frame in tracking."""
    if _SOLVE1 is None:  # pragma: no cover
        try:
            return np.linalg.solve(h, g)
        except np.linalg.LinAlgError:
            return None
    with np.errstate(invalid="raise", over="ignore", divide="ignore", under="ignore"):
        try:
            return _SOLVE1(h, g, signature="dd->d")
        except FloatingPointError:  # LAPACK's singular-matrix report
            return None

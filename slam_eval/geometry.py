"""Small rigid-motion helpers (4×4 homogeneous matrices, OpenCV rotation vectors, projection).

Conventions: ``T_cw`` maps world points into the camera frame (what PnP returns), ``T_wc`` is the
camera-to-world pose written to TUM trajectories; points are rows ``(N, 3)`` in metres.
"""

from __future__ import annotations

import cv2
import numpy as np


def invert(t: np.ndarray) -> np.ndarray:
    """Inverse of a rigid ``(4, 4)`` transform."""
    out = np.eye(4)
    r = t[:3, :3]
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t[:3, 3]
    return out


def from_rvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """``(4, 4)`` transform from an OpenCV rotation vector and translation."""
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    out[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
    return out


def to_rvec(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rvec (3, 1), tvec (3, 1))`` of a ``(4, 4)`` transform, for OpenCV's PnP functions."""
    rvec = cv2.Rodrigues(np.ascontiguousarray(t[:3, :3]))[0]
    return rvec.reshape(3, 1), t[:3, 3].reshape(3, 1).copy()


def transform(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a ``(4, 4)`` transform to ``(N, 3)`` points."""
    return points @ t[:3, :3].T + t[:3, 3]


def project(k: np.ndarray, points_cam: np.ndarray) -> np.ndarray:
    """``(N, 2)`` pixel coordinates of camera-frame points (pinhole, no distortion)."""
    z = points_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k[0, 0] * points_cam[:, 0] / z + k[0, 2]
        v = k[1, 1] * points_cam[:, 1] / z + k[1, 2]
    return np.stack([u, v], axis=1)


def rotation_angle_deg(r: np.ndarray) -> float:
    """Angle of a ``(3, 3)`` rotation, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))

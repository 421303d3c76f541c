"""Rolling-shutter correction of a frame's keypoints.

A Kinect's colour camera reads its rows out one after the other: row ``r`` of an image stamped
``t`` is exposed at ``t + (r / (H - 1) - 0.5) · readout`` (the stamp is the middle row's time).
While the camera turns, the image is skewed: on a hand-held recording turning at 40°/s with a
30 ms readout the top and bottom rows see the scene 1.2° apart, ~11 px at 640×480. A tracker
with one pose per frame (ORB-SLAM2's, ours) reads that skew as a wrong pose, and bundle
adjustment cannot take it out.

:func:`unroll` moves each keypoint to where the camera would have seen it at the stamp, from the
camera's motion during the readout: the keypoint's 3D point (from its depth; without depth its
ray, rotated only) is taken from the camera at its row's time to the camera at the stamp and
projected again. Two passes (:meth:`~.tracker.Tracker.unroll` and
:meth:`~.tracker.Tracker.unroll_tracked`): before tracking with the constant-velocity model (the
last two tracked frames' relative pose per second), and once the frame is tracked with its own
velocity over the last frame interval, after which its pose is refined on the same matches. The
first frame and the first after a lost track are not corrected. The positions in the image (``xy``, which the filters read labels at) stay; the
undistorted positions, depths and 3D points (``uv``, ``depth``, ``points``, which tracking and
mapping use) are corrected.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ..frontend.orb import Features
from ..geometry import project


def readout_of(setting: float | None, camera_readout: float | None) -> tuple[float, str]:
    """The readout the tracker corrects for and where it came from: the setting when given,
    else the camera's declared readout, else none (a global shutter)."""
    if setting is not None:
        return float(setting), "slam.tracker.readout"
    if camera_readout is not None:
        return float(camera_readout), "the camera's declared readout"
    return 0.0, "none (the camera declares no readout)"


def twist(velocity: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Angular (rad/s) and linear (m/s) velocity of the camera, in its own frame, from the
    constant-velocity model ``velocity`` (``T_c(t) c(t-dt)``, 4×4) over ``dt`` seconds."""
    if not dt > 0:
        raise ValueError(f"dt must be > 0 s, got {dt}")
    omega = cv2.Rodrigues(np.ascontiguousarray(velocity[:3, :3]))[0].reshape(3) / dt
    return omega, velocity[:3, 3] / dt


def row_times(rows: np.ndarray, height: int, readout: float) -> np.ndarray:
    """Seconds from the stamp to the exposure of image rows ``rows`` (the middle row: 0)."""
    return (np.asarray(rows, np.float64) / max(height - 1, 1) - 0.5) * readout


def unroll(
    features: Features,
    omega: np.ndarray,
    linear: np.ndarray,
    readout: float,
    k: np.ndarray,
    height: int,
) -> Features:
    """The keypoints as the camera would have seen them at the stamp (see the module).

    ``omega`` / ``linear``: the camera's velocity (:func:`twist`); ``readout`` seconds from the
    top row to the bottom row; ``k`` the 3×3 calibration of the undistorted positions; ``height``
    the image height in pixels. Keypoints whose corrected point falls behind the camera keep
    their position and lose their depth.
    """
    if len(features) == 0 or readout == 0:
        return features
    tau = row_times(features.xy[:, 1], height, readout)[:, None]
    has = features.depth > 0
    # a keypoint without depth: its ray (a point at unit depth, moved by the rotation only)
    rays = np.c_[(features.uv - k[:2, 2]) / np.diag(k)[:2], np.ones(len(features))]
    seen = np.where(has[:, None], features.points, rays)
    # X_c(t) = exp(-τ ξ) X_c(t+τ): first the rotation back, then the translation (rays: none).
    moved = Rotation.from_rotvec(-tau * omega).apply(seen) - has[:, None] * (tau * linear)
    ahead = moved[:, 2] > 1e-6
    uv = features.uv.copy()
    uv[ahead] = project(k, moved[ahead])
    depth = np.where(ahead, moved[:, 2], 0.0).astype(features.depth.dtype)
    depth[~has] = 0.0
    points = np.where((has & ahead)[:, None], moved, np.nan)
    return replace(features, uv=uv, depth=depth, points=points)

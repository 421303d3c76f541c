"""The ORB-SLAM3 settings file (OpenCV ``%YAML:1.0``, ``File.version: "1.0"``, as ORB-SLAM3's
RGB-D TUM examples): written from the sequence's camera and ``system.*``
(:func:`settings_yaml`), or the user's ``system.settings_file``; either is checked the way
ORB-SLAM3 reads it (:func:`check_settings`), since ORB-SLAM3 ends the process on a missing or
mistyped key.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.tum_io import CameraIntrinsics, StrPath

from .config import OrbSlam3Config

_VIEWER = {
    "Viewer.KeyFrameSize": 0.05,
    "Viewer.KeyFrameLineWidth": 1.0,
    "Viewer.GraphLineWidth": 0.9,
    "Viewer.PointSize": 2.0,
    "Viewer.CameraSize": 0.08,
    "Viewer.CameraLineWidth": 3.0,
    "Viewer.ViewpointX": 0.0,
    "Viewer.ViewpointY": -0.7,
    "Viewer.ViewpointZ": -1.8,
    "Viewer.ViewpointF": 500.0,
}
# What ORB-SLAM3's Settings class reads for an RGB-D pinhole camera, and the type it insists on.
_REQUIRED: dict[str, str] = {
    "Camera.type": "string",
    "Camera1.fx": "real",
    "Camera1.fy": "real",
    "Camera1.cx": "real",
    "Camera1.cy": "real",
    "Camera.width": "int",
    "Camera.height": "int",
    "Camera.fps": "int",
    "Camera.RGB": "int",
    "RGBD.DepthMapFactor": "real",
    "Stereo.ThDepth": "real",
    "Stereo.b": "real",
    "ORBextractor.nFeatures": "int",
    "ORBextractor.scaleFactor": "real",
    "ORBextractor.nLevels": "int",
    "ORBextractor.iniThFAST": "int",
    "ORBextractor.minThFAST": "int",
    **dict.fromkeys(_VIEWER, "real"),
}
_DISTORTION_KEYS = ("Camera1.k1", "Camera1.k2", "Camera1.p1", "Camera1.p2", "Camera1.k3")


def _real(value: float) -> str:
    """A float OpenCV's YAML reader takes as real (``500`` would read as an int)."""
    text = repr(float(value))
    return text if any(c in text for c in ".en") else text + ".0"


def settings_yaml(camera: CameraIntrinsics, config: OrbSlam3Config, fps: int) -> str:
    """ORB-SLAM3 RGB-D settings for ``camera`` (depth passed in metres: ``DepthMapFactor`` 1,
    colour passed in RGB order: ``Camera.RGB`` 1)."""
    if len(camera.distortion) not in (4, 5):
        raise UssSlamError(
            f"system=orbslam3: ORB-SLAM3's pinhole camera takes 4 or 5 distortion coefficients "
            f"(k1 k2 p1 p2 [k3]); the sequence's camera has {len(camera.distortion)}"
        )
    lines = [
        "%YAML:1.0",
        "# ORB-SLAM3 RGB-D settings written by uss-slam system=orbslam3 (TUM example layout)",
        'File.version: "1.0"',
        'Camera.type: "PinHole"',
        f"Camera1.fx: {_real(camera.fx)}",
        f"Camera1.fy: {_real(camera.fy)}",
        f"Camera1.cx: {_real(camera.cx)}",
        f"Camera1.cy: {_real(camera.cy)}",
    ]
    lines += [
        f"{key}: {_real(value)}"
        for key, value in zip(_DISTORTION_KEYS, camera.distortion, strict=False)
    ]
    lines += [
        f"Camera.width: {int(camera.width)}",
        f"Camera.height: {int(camera.height)}",
        f"Camera.fps: {int(fps)}",
        "Camera.RGB: 1",
        f"Stereo.ThDepth: {_real(config.th_depth)}",
        f"Stereo.b: {_real(config.baseline)}",
        "RGBD.DepthMapFactor: 1.0",
        f"ORBextractor.nFeatures: {int(config.n_features)}",
        f"ORBextractor.scaleFactor: {_real(config.scale_factor)}",
        f"ORBextractor.nLevels: {int(config.n_levels)}",
        f"ORBextractor.iniThFAST: {int(config.ini_fast)}",
        f"ORBextractor.minThFAST: {int(config.min_fast)}",
    ]
    lines += [f"{key}: {_real(value)}" for key, value in _VIEWER.items()]
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class SettingsInfo:
    """What the run needs to know of a checked settings file."""

    path: Path
    width: int
    height: int
    depth_factor: float
    """``RGBD.DepthMapFactor``: depth is passed as metres × this."""
    rgb: bool
    """``Camera.RGB``: colour is passed in RGB order if True, else BGR."""


def check_settings(path: StrPath, image_size: tuple[int, int] | None = None) -> SettingsInfo:
    """Check an ORB-SLAM3 RGB-D settings file the way ORB-SLAM3's ``Settings`` reads it.

    Raises :class:`DataFormatError` naming the file and the key for what ORB-SLAM3 would abort
    the process on: an unreadable file, no ``File.version: "1.0"``, a missing key or a value of
    the wrong type (``Camera.fps`` must be an integer, ...), a camera type other than PinHole, or
    an image size other than the sequence's ``image_size`` ``(width, height)``.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "file not found (system.settings_file)")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as err:  # OpenCV's parser errors surface as either
        text = str(err.__cause__ or err).strip()
        first = text.splitlines()[-1] if text else "parse error"
        raise DataFormatError(path, f"not an OpenCV YAML file ({first})") from None
    try:
        if not storage.isOpened():
            raise DataFormatError(path, "not an OpenCV YAML file")
        version = storage.getNode("File.version")
        if version.empty() or not version.isString() or version.string() != "1.0":
            raise DataFormatError(
                path, 'expected File.version: "1.0" (the ORB-SLAM3 settings format this reads)'
            )
        values: dict[str, Any] = {}
        for key, kind in _REQUIRED.items():
            node = storage.getNode(key)
            if node.empty():
                raise DataFormatError(path, f"missing {key} (ORB-SLAM3 requires it)")
            ok = {
                "string": node.isString(),
                "int": node.isInt(),
                "real": node.isReal() or node.isInt(),
            }[kind]
            if not ok:
                what = {"string": "a string", "int": "an integer", "real": "a number"}[kind]
                raise DataFormatError(path, f"{key} must be {what} (ORB-SLAM3 aborts otherwise)")
            values[key] = node.string() if kind == "string" else node.real()
        if values["Camera.type"] != "PinHole":
            raise DataFormatError(
                path, f'Camera.type must be "PinHole" for RGB-D, got {values["Camera.type"]!r}'
            )
        if not storage.getNode("Camera1.k1").empty():
            for key in _DISTORTION_KEYS[:4]:
                node = storage.getNode(key)
                if node.empty() or not (node.isReal() or node.isInt()):
                    raise DataFormatError(path, f"Camera1.k1 is set, so {key} must be a number")
    finally:
        storage.release()
    width, height = int(values["Camera.width"]), int(values["Camera.height"])
    if image_size is not None and (width, height) != tuple(image_size):
        raise DataFormatError(
            path,
            f"Camera.width x Camera.height is {width}x{height} but the sequence's images are "
            f"{image_size[0]}x{image_size[1]}",
        )
    factor = float(values["RGBD.DepthMapFactor"])
    if not factor > 0:
        raise DataFormatError(path, f"RGBD.DepthMapFactor must be > 0, got {factor}")
    return SettingsInfo(path, width, height, factor, bool(values["Camera.RGB"]))


def frame_rate(stamps: np.ndarray) -> int:
    """Frames per second from the median stamp spacing (at least 1)."""
    if len(stamps) < 2:
        return 30
    step = float(np.median(np.diff(stamps)))
    return max(1, round(1.0 / step)) if step > 0 else 30

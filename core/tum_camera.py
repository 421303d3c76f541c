"""The camera of a TUM RGB-D sequence: pinhole intrinsics with distortion and depth scale
(:class:`CameraIntrinsics`, read from and written to an ``intrinsics.yaml``), the published
Kinect calibrations (:data:`TUM_CAMERAS`) and which camera a sequence uses
(:func:`resolve_camera`). NumPy and YAML only; :mod:`.tum_io` re-exports every name."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
import yaml

from .errors import DataFormatError, UssSlamError
from .paths import naming, read_yaml

DEPTH_SCALE = 5000.0
"""Depth PNG units per metre."""

StrPath = str | PathLike[str]

INTRINSICS_FILE = "intrinsics.yaml"


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole camera with optional OpenCV distortion ``(k1, k2, p1, p2, k3)``; pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    depth_scale: float = DEPTH_SCALE
    depth_noise: float | None = None
    """The depth sensor's axial noise as ``k`` of ``σ_z = k·z²`` (metres⁻¹), when it is known
    (a synthetic sensor's); None = unknown, as for a real Kinect, whose depth also suffers from
    its capture timing (the SLAM back end then uses ORB-SLAM2's noise model)."""
    readout: float | None = None
    """Seconds the colour camera takes to read its rows out, top to bottom (a rolling shutter),
    when it is known; None = not declared (the SLAM tracker then corrects nothing)."""

    @property
    def matrix(self) -> np.ndarray:
        """The 3×3 calibration matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.distortion)

    def scaled(self, width: int, height: int) -> CameraIntrinsics:
        """The same camera for an image resized to ``width × height``."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=width,
            height=height,
            distortion=self.distortion,
            depth_scale=self.depth_scale,
            depth_noise=self.depth_noise,
            readout=self.readout,
        )

    def to_yaml(self, path: StrPath) -> None:
        data = {
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "width": int(self.width),
            "height": int(self.height),
            "distortion": [float(d) for d in self.distortion],
            "depth_scale": float(self.depth_scale),
        }
        if self.depth_noise is not None:
            data["depth_noise"] = float(self.depth_noise)
        if self.readout is not None:
            data["readout"] = float(self.readout)
        Path(path).write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")

    @classmethod
    def from_yaml(cls, path: StrPath) -> CameraIntrinsics:
        """Read an ``intrinsics.yaml``, checking every value: ``fx``, ``fy`` and ``depth_scale``
        finite and > 0, ``width`` / ``height`` whole numbers > 0, the principal point inside the
        image, 4, 5 or 8 finite distortion coefficients; errors name the file and the key."""
        path = Path(path)
        data = read_yaml(path, "expected an intrinsics YAML file")
        required = ("fx", "fy", "cx", "cy", "width", "height")
        if not isinstance(data, dict) or any(k not in data for k in required):
            raise DataFormatError(path, f"expected a mapping with keys {', '.join(required)}")
        unknown = sorted(str(k) for k in data if k not in INTRINSICS_KEYS)
        if unknown:
            raise DataFormatError(
                path, f"unknown key {unknown[0]!r}; expected {', '.join(INTRINSICS_KEYS)}"
            )

        def number(key: str, value: object) -> float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise DataFormatError(path, f"{key} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise DataFormatError(path, f"{key} must be a finite number, got {value}")
            return float(value)

        def positive(key: str) -> float:
            value = number(key, data[key])
            if value <= 0:
                raise DataFormatError(path, f"{key} must be > 0, got {value:g}")
            return value

        def size(key: str) -> int:
            value = positive(key)
            if not value.is_integer():
                raise DataFormatError(path, f"{key} must be a whole number of pixels, got {value}")
            return int(value)

        fx, fy = positive("fx"), positive("fy")
        width, height = size("width"), size("height")
        cx, cy = number("cx", data["cx"]), number("cy", data["cy"])
        for key, value, limit in (("cx", cx, width), ("cy", cy, height)):
            if not 0 <= value < limit:
                side = "width" if key == "cx" else "height"
                raise DataFormatError(
                    path, f"{key} must lie inside the image (0 <= {key} < {side} {limit}), "
                    f"got {value:g}"
                )  # fmt: skip
        coefficients = data.get("distortion", [0.0] * 5)
        if not isinstance(coefficients, list) or len(coefficients) not in (4, 5, 8):
            count = len(coefficients) if isinstance(coefficients, list) else "no list"
            raise DataFormatError(
                path, f"distortion needs a list of 4, 5 or 8 coefficients, got {count}"
            )
        distortion = tuple(number(f"distortion[{k}]", d) for k, d in enumerate(coefficients))
        depth_scale = positive("depth_scale") if "depth_scale" in data else DEPTH_SCALE
        depth_noise = None
        if data.get("depth_noise") is not None:
            depth_noise = number("depth_noise", data["depth_noise"])
            if depth_noise < 0:
                raise DataFormatError(path, f"depth_noise must be >= 0, got {depth_noise:g}")
        readout = None
        if data.get("readout") is not None:
            readout = number("readout", data["readout"])
            if not 0 <= readout < 1:
                raise DataFormatError(
                    path, f"readout must be >= 0 and < 1 (seconds per frame), got {readout:g}"
                )
        return cls(fx, fy, cx, cy, width, height, distortion, depth_scale, depth_noise, readout)


INTRINSICS_KEYS = (
    "fx", "fy", "cx", "cy", "width", "height", "distortion", "depth_scale", "depth_noise",
    "readout",
)  # fmt: skip
"""The keys of an ``intrinsics.yaml`` (:meth:`CameraIntrinsics.from_yaml`)."""

KINECT_READOUT = 0.03
"""Rolling-shutter readout assumed for the TUM recordings' colour cameras, seconds: their
sensors read out line by line at 30 frames/s, so a frame's rows span nearly the frame period
(33 ms less the blanking). Not fitted to any recording; the synthetic ``kinect`` timing uses
the same value."""

TUM_CAMERAS: dict[str, CameraIntrinsics] = {
    # Published calibrations of the TUM RGB-D Kinects (640×480), with their distortion.
    "fr1": CameraIntrinsics(
        517.3, 516.5, 318.6, 255.3, 640, 480, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
        readout=KINECT_READOUT,
    ),
    "fr2": CameraIntrinsics(
        520.9, 521.0, 325.1, 249.7, 640, 480, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172),
        readout=KINECT_READOUT,
    ),
    "fr3": CameraIntrinsics(535.4, 539.2, 320.1, 247.6, 640, 480, readout=KINECT_READOUT),
}  # fmt: skip


def resolve_camera(
    spec: str | None, sequence_dir: Path, image_size: tuple[int, int], key: str = "camera"
) -> tuple[CameraIntrinsics, str]:
    """The camera for ``spec`` and a short description of where it came from.

    ``None``/``"auto"``: the sequence's ``intrinsics.yaml`` if present, else TUM fr3.
    ``"fr1" | "fr2" | "fr3"``: TUM's published calibration (with distortion for fr1/fr2), rescaled
    when the images are not 640×480. Anything else is a path to an ``intrinsics.yaml``-format file,
    which must match the image size exactly. ``image_size`` is ``(width, height)``; ``key`` is the
    config key errors name.
    """
    width, height = image_size
    if spec is None or str(spec).strip().lower() in ("", "auto", "none", "null"):
        own = Path(sequence_dir) / INTRINSICS_FILE
        if os.path.lexists(own):  # a folder or a broken link of that name: the reader's line
            return _same_size(CameraIntrinsics.from_yaml(own), own, image_size), str(own)
        spec = "fr3"
    name = str(spec).strip()
    if name.lower() in TUM_CAMERAS:
        cam = TUM_CAMERAS[name.lower()]
        if (cam.width, cam.height) != (width, height):
            cam = cam.scaled(width, height)
        return cam, name.lower()
    path = Path(os.path.expanduser(name))
    if not path.exists():
        raise UssSlamError(
            f"{key}={name!r}: not one of {', '.join(sorted(TUM_CAMERAS))} "
            f"and no such file (expected a camera name or a path to an {INTRINSICS_FILE})"
        )
    if path.is_dir():
        raise DataFormatError(path, f"is a folder; expected an {INTRINSICS_FILE}-format file")
    with naming(key, path):  # the reader's line about the file given names the setting too
        return _same_size(CameraIntrinsics.from_yaml(path), path, image_size), str(path)


def _same_size(cam: CameraIntrinsics, path: Path, image_size: tuple[int, int]) -> CameraIntrinsics:
    if (cam.width, cam.height) != image_size:
        raise DataFormatError(
            path,
            f"camera is {cam.width}x{cam.height} but the sequence's images are "
            f"{image_size[0]}x{image_size[1]}",
        )
    return cam

"""``system.*`` of ``uss-slam system=orbslam3`` (``configs/system/orbslam3.yaml``): ORB-SLAM3's
own settings, checked before any frame is read, and the check of its vocabulary file.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.ranges import MAX_FEATURES
from uss_slam.core.schema import SchemaError, check_fields, ranged, validate

from .masking import FILLS
from .vocabulary import read_header

INSTALL_HINT = "pip install 'uss-slam[orbslam3]'"
VOCAB_HINT = (
    "build a small one from frames with `uss-vocab build --out vocab.txt SEQUENCE_DIR [...]` "
    "(or use ORB-SLAM3's ORBvoc.txt) and pass system.vocabulary=vocab.txt"
)


@dataclass(frozen=True)
class OrbSlam3Config:
    """``system.*`` of ``configs/system/orbslam3.yaml`` (ORB-SLAM3's own settings)."""

    vocabulary: Optional[str] = None  # noqa: UP045 (OmegaConf)
    """DBoW2 text vocabulary file (``uss-vocab build`` or ORB-SLAM3's ``ORBvoc.txt``)."""
    repeats: int = ranged(3, min=1)
    settings_file: Optional[str] = None  # noqa: UP045
    """An ORB-SLAM3 settings YAML to use instead of the one written from the sequence's camera."""
    n_features: int = ranged(1000, min=1, max=MAX_FEATURES)
    scale_factor: float = ranged(1.2, gt=1.0)
    n_levels: int = ranged(8, min=1)
    ini_fast: int = ranged(20, min=1, max=255)
    min_fast: int = ranged(7, min=1, max=255)
    baseline: float = ranged(0.0747, gt=0)
    """m, ``Stereo.b``: the virtual stereo baseline of RGB-D mode (TUM examples: bf = 40)."""
    th_depth: float = ranged(40.0, gt=0)
    """``Stereo.ThDepth``: close points are nearer than ``th_depth × baseline`` (~3 m)."""
    fps: Optional[int] = ranged(None, min=1)  # noqa: UP045
    """``Camera.fps`` (ORB-SLAM3 inserts a keyframe at least every fps frames); None = from
    the selected frames' stamps."""
    realtime: bool = True
    """Feed frames no faster than their stamps (as ORB-SLAM3's ``rgbd_tum`` example)."""
    blank_value: int = ranged(128, min=0, max=255)
    """Grey level (0-255) of the blanked dynamic pixels in the colour image."""
    blank_fill: str = ranged("grey", choices=FILLS)
    """``grey`` (flat ``blank_value``) or ``inpaint`` (continued from the pixels around the
    mask: a weaker edge where a mask covers only part of a walker)."""

    def __post_init__(self) -> None:
        check_fields(self, "system")  # the ranges above, one line naming system.<key>
        if self.min_fast > self.ini_fast:  # the one rule across keys
            raise SchemaError(
                "system.min_fast", f"an integer <= system.ini_fast ({self.ini_fast})", self.min_fast
            )


def check_system(values: Mapping[str, Any]) -> OrbSlam3Config:
    """``system.*`` as composed (``name`` left out): unknown keys, types and ranges, each one
    line naming its ``system.<key>`` (the schema's), then the rule across keys."""
    values = {k: v for k, v in values.items() if k != "name"}
    validate(values, OrbSlam3Config, "system")
    return OrbSlam3Config(**values)


def check_vocabulary(vocabulary: str | None) -> Path:
    """The vocabulary path, checked (exists, DBoW2 text header) before ORB-SLAM3 sees it."""
    if vocabulary is None or not str(vocabulary).strip():
        raise UssSlamError(f"system.vocabulary is not set: ORB-SLAM3 needs one; {VOCAB_HINT}")
    path = Path(os.path.expanduser(str(vocabulary)))
    if not path.is_file():
        raise UssSlamError(f"system.vocabulary={vocabulary}: file not found; {VOCAB_HINT}")
    try:
        read_header(path)
    except DataFormatError as err:
        where = "" if err.line is None else f"line {err.line}: "
        raise UssSlamError(f"system.vocabulary={vocabulary}: {where}{err.detail}") from None
    return path

"""``system.*`` of ``uss-slam system=orbslam3`` (``configs/system/orbslam3.yaml``): ORB-SLAM3's
own settings, checked before any frame is read, and the check of its vocabulary file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from uss_slam.core.errors import DataFormatError, UssSlamError

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

    vocabulary: str | None = None
    """DBoW2 text vocabulary file (``uss-vocab build`` or ORB-SLAM3's ``ORBvoc.txt``)."""
    repeats: int = 3
    settings_file: str | None = None
    """An ORB-SLAM3 settings YAML to use instead of the one written from the sequence's camera."""
    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    ini_fast: int = 20
    min_fast: int = 7
    baseline: float = 0.0747
    """m, ``Stereo.b``: the virtual stereo baseline of RGB-D mode (TUM examples: bf = 40)."""
    th_depth: float = 40.0
    """``Stereo.ThDepth``: close points are nearer than ``th_depth × baseline`` (~3 m)."""
    fps: int | None = None
    """``Camera.fps`` (ORB-SLAM3 inserts a keyframe at least every fps frames); None = from
    the selected frames' stamps."""
    realtime: bool = True
    """Feed frames no faster than their stamps (as ORB-SLAM3's ``rgbd_tum`` example)."""
    blank_value: int = 128
    """Grey level (0-255) of the blanked dynamic pixels in the colour image."""
    blank_fill: str = "grey"
    """``grey`` (flat ``blank_value``) or ``inpaint`` (continued from the pixels around the
    mask: a weaker edge where a mask covers only part of a walker)."""

    def __post_init__(self) -> None:
        checks = [
            (self.repeats >= 1, "repeats", "an integer >= 1"),
            (self.n_features >= 1, "n_features", "an integer >= 1"),
            (self.scale_factor > 1.0, "scale_factor", "a number > 1"),
            (self.n_levels >= 1, "n_levels", "an integer >= 1"),
            (0 < self.min_fast <= self.ini_fast, "min_fast", "0 < min_fast <= ini_fast"),
            (self.baseline > 0, "baseline", "a number > 0 (metres)"),
            (self.th_depth > 0, "th_depth", "a number > 0"),
            (self.fps is None or self.fps >= 1, "fps", "null or an integer >= 1"),
            (0 <= self.blank_value <= 255, "blank_value", "a grey level 0..255"),
            (self.blank_fill in FILLS, "blank_fill", " or ".join(FILLS)),
        ]
        for ok, key, expected in checks:
            if not ok:
                raise UssSlamError(f"system.{key}={getattr(self, key)!r}: expected {expected}")


def check_vocabulary(vocabulary: str | None) -> Path:
    """The vocabulary path, checked (exists, DBoW2 text header) before ORB-SLAM3 sees it."""
    if vocabulary is None or not str(vocabulary).strip():
        raise UssSlamError(f"system.vocabulary is not set: ORB-SLAM3 needs one; {VOCAB_HINT}")
    path = Path(str(vocabulary)).expanduser()
    if not path.is_file():
        raise UssSlamError(f"system.vocabulary={vocabulary}: file not found; {VOCAB_HINT}")
    try:
        read_header(path)
    except DataFormatError as err:
        where = "" if err.line is None else f"line {err.line}: "
        raise UssSlamError(f"system.vocabulary={vocabulary}: {where}{err.detail}") from None
    return path

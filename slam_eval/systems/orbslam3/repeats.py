"""The repeats of an ORB-SLAM3 run: one run's trajectory, tracking states and times, and the
choice of the median run by ATE RMSE (:func:`~..scoring.repeats.median_index`, shared with the
harness's repeats).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uss_slam.core.tum_io import Trajectory, read_trajectory, write_trajectory

from ...scoring.evaluation import Evaluation

TRACKING_STATES = (
    "SYSTEM_NOT_READY",
    "NO_IMAGES_YET",
    "NOT_INITIALIZED",
    "OK",
    "RECENTLY_LOST",
    "LOST",
    "OK_KLT",
)
"""ORB-SLAM3's tracking states (``pyorbslam3.TrackingState``); only ``OK`` is tracked."""


@dataclass
class RepeatResult:
    """One ORB-SLAM3 run: its trajectory, per-frame states and times."""

    index: int
    trajectory_path: Path
    trajectory: Trajectory
    states: list[str]
    track_s: float
    load_s: float
    evaluation: Evaluation | None = None

    @property
    def state_counts(self) -> dict[str, int]:
        counts = Counter(self.states)
        return {s: counts[s] for s in TRACKING_STATES if counts[s]}

    @property
    def ate_rmse(self) -> float | None:
        ate = self.evaluation.ate if self.evaluation else None
        return None if ate is None else float(ate.stats.rmse)


def read_estimate(path: Path) -> Trajectory:
    """ORB-SLAM3's saved trajectory; when it saved none (it never initialised, so no frame has a
    pose) an empty one is written in its place, so that every repeat has its file."""
    if not path.is_file():
        empty = Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)), path)
        write_trajectory(path, empty, comment="ORB-SLAM3 never initialised: no frame has a pose")
    return read_trajectory(path)

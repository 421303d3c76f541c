"""The repeats of an ORB-SLAM3 run: one run's trajectory, tracking states and times, and the
choice of the median run by ATE RMSE (:func:`~..scoring.repeats.median_index`, shared with the
harness's repeats).
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.tum_io import Trajectory, read_trajectory, write_trajectory

from ...scoring.evaluation import Evaluation

log = logging.getLogger(__name__)

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
    thread: dict[str, Any] | None = None
    """With ``segment=thread``: the worker's figures (masks ``delivered``, ``blanked_fraction``,
    ``carry_ms`` per frame)."""

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
    pose) an empty one is written in its place, so that every repeat has its file. Rows it
    wrote again for frames it did not track are removed first (:func:`drop_repeated_rows`)."""
    if not path.is_file():
        empty = Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)), path)
        write_trajectory(path, empty, comment="ORB-SLAM3 never initialised: no frame has a pose")
    repeated = drop_repeated_rows(path)
    if repeated:
        log.warning(
            "%s: %d rows repeated the row before them (ORB-SLAM3's placeholder for a frame it "
            "did not track, e.g. RECENTLY_LOST); removed, those frames count as without a pose",
            path,
            repeated,
        )
    return read_trajectory(path)


def drop_repeated_rows(path: Path) -> int:
    """Remove, in place, the rows of a saved ORB-SLAM3 trajectory that repeat the row before
    them exactly (stamp and pose); returns how many.

    ORB-SLAM2/3's ``Tracking`` keeps one entry per frame. A frame without a pose of its own
    gets a copy of the last entry, time stamp included. ``SaveTrajectoryTUM`` skips the copies
    only while the state is ``LOST``, so frames in ORB-SLAM3's ``RECENTLY_LOST`` come out as
    duplicate rows. A stamp repeated with another pose is left for
    :func:`~uss_slam.core.tum_io.read_trajectory` to report."""
    lines = path.read_text(encoding="utf-8").splitlines()
    kept: list[str] = []
    last: list[str] | None = None
    dropped = 0
    for line in lines:
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            kept.append(line)
            continue
        if fields == last:
            dropped += 1
            continue
        kept.append(line)
        last = fields
    if dropped:
        note = (
            f"# {dropped} rows that repeated the row before (frames ORB-SLAM3 did not track) "
            "were removed"
        )
        path.write_text("\n".join([note, *kept]) + "\n", encoding="utf-8")
    return dropped

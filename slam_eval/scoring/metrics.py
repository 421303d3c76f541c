"""Trajectory error metrics: timestamp association, Umeyama alignment, ATE and RPE. NumPy only.

The semantics follow evo (``evo_ape`` / ``evo_rpe``, MichaelGrupp/evo) so that numbers agree with it
to 1e-9 m for the same settings:

- **Association** (:func:`associate_trajectories`, evo's ``associate_trajectories`` with
  ``SyncMethod.nearest_time``): the trajectory with *fewer* poses is walked (the estimate when both
  have as many) and each of its stamps is matched to the *nearest* stamp of the other one, if that
  is at most ``max_diff`` seconds away (inclusive); on an exact tie the earlier stamp wins. A
  pose of the longer trajectory may be matched more than once. ``offset`` is added to the
  estimate's stamps (evo's ``--t_offset``, TUM's ``--offset``).
- **Alignment** (:func:`align_umeyama`): Umeyama's closed form on the associated positions;
  ``se3`` = ``evo_ape --align``, ``sim3`` = ``--align --correct_scale``, ``none`` = no alignment.
- **ATE** (:func:`ate`): per associated pose, the Euclidean distance between the aligned estimated
  position and the ground-truth position (evo's ``translation_part`` APE), in metres.
- **RPE** (:func:`rpe`): ``E_ij = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` for ground truth ``Q`` and estimate
  ``P`` over the associated poses; translation error ``‖t(E_ij)‖`` (metres) and rotation error
  ``angle(R(E_ij))`` (degrees). ``unit="frames"`` is evo's ``--delta_unit f`` without
  ``--all_pairs``: pairs ``(0, d), (d, 2d), …``. ``unit="seconds"`` (evo has no time unit) follows
  TUM's ``evaluate_rpe.py --fixed_delta --delta_unit s``: every associated pose ``i`` is paired
  with the associated pose whose estimate stamp is nearest to ``t_i + delta``; the pair counts if
  its actual interval is within ``SECONDS_DELTA_REL_TOL * delta`` (10%) of ``delta``, otherwise
  (a gap in the association, or ``delta`` finer than the sampling) it is skipped, and counted in
  ``RpeResult.skipped`` when ``t_i + delta`` lies within the trajectory's time span.
  Errors are not divided by the interval (TUM and evo do not either): with ``delta=1`` seconds
  the translation error is the drift in metres per second.

Statistics (:class:`ErrorStats`): RMSE, mean, median, population standard deviation, min, max.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.tum_io import Trajectory, quat_to_matrix

DEFAULT_MAX_DIFF = 0.02
"""Largest stamp difference (seconds) of an associated pose pair, as TUM's tools."""

MIN_ASSOCIATED_POSES = 3
"""Fewest associated poses accepted: Umeyama alignment needs three non-collinear points."""

ALIGNMENTS = ("se3", "sim3", "none")
DELTA_UNITS = ("frames", "seconds")

SECONDS_DELTA_REL_TOL = 0.1
"""Relative tolerance on the interval of a ``unit="seconds"`` RPE pair (evo's ``rel_delta_tol``)."""


class AssociationError(UssSlamError, ValueError):
    """Two trajectories share too few poses (by timestamp) to be compared."""


class NoPairsError(AssociationError):
    """No pose pairs ``delta`` apart (RPE): the delta, not the files, is what to change."""


class AlignmentError(UssSlamError, ValueError):
    """The associated positions do not determine a rigid alignment (collinear or identical)."""


# --------------------------------------------------------------------------- statistics


@dataclass(frozen=True)
class ErrorStats:
    """Summary of per-pair errors (metres or degrees): RMSE, mean, median, std, min, max, pairs.

    ``std`` is the population standard deviation (divides by ``pairs``), as evo and TUM's tools.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    pairs: int

    @classmethod
    def from_errors(cls, errors: np.ndarray) -> ErrorStats:
        """Statistics of a non-empty ``(N,)`` error array (computed the way evo computes them)."""
        e = np.asarray(errors, dtype=np.float64)
        if e.ndim != 1 or len(e) == 0:
            raise ValueError(f"need a non-empty 1-D error array, got shape {e.shape}")
        return cls(
            rmse=math.sqrt(np.mean(np.power(e, 2))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            pairs=len(e),
        )

    def as_dict(self) -> dict[str, float | int]:
        """``{"rmse", "mean", "median", "std", "min", "max", "pairs"}`` (JSON-ready)."""
        return {
            "rmse": self.rmse,
            "mean": self.mean,
            "median": self.median,
            "std": self.std,
            "min": self.min,
            "max": self.max,
            "pairs": self.pairs,
        }


# --------------------------------------------------------------------------- association


def _name(traj: Trajectory, role: str) -> str:
    return str(traj.path) if traj.path is not None else f"<{role} trajectory>"


def _check_trajectory(traj: Trajectory, role: str) -> None:
    """Shapes, finiteness and strictly increasing stamps of an in-memory trajectory.

    ``read_trajectory`` already checks files line by line; this guards trajectories built in code.
    """
    name = _name(traj, role)
    n = len(traj.stamps)
    if n == 0:
        raise DataFormatError(name, "no poses (expected lines 'timestamp tx ty tz qx qy qz qw')")
    if (
        np.shape(traj.stamps) != (n,)
        or np.shape(traj.positions) != (n, 3)
        or np.shape(traj.quaternions) != (n, 4)
    ):
        raise DataFormatError(
            name,
            f"inconsistent shapes: stamps {np.shape(traj.stamps)}, positions "
            f"{np.shape(traj.positions)}, quaternions {np.shape(traj.quaternions)}",
        )
    for what, values in (
        ("stamps", traj.stamps),
        ("positions", traj.positions),
        ("quaternions", traj.quaternions),
    ):
        if not np.all(np.isfinite(values)):
            raise DataFormatError(name, f"{what} must be finite numbers")
    steps = np.diff(traj.stamps)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise DataFormatError(
            name,
            f"timestamps must strictly increase: pose {k} has {traj.stamps[k]:.6f} after "
            f"{traj.stamps[k - 1]:.6f}",
        )


def matching_time_indices(
    stamps_1: np.ndarray, stamps_2: np.ndarray, *, max_diff: float, offset_2: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """For each stamp of ``stamps_1`` the index of the nearest stamp of ``stamps_2 + offset_2``.

    ``stamps_2`` must be sorted. Pairs further apart than ``max_diff`` seconds (inclusive bound)
    are dropped; on an exact tie the earlier stamp of ``stamps_2`` wins; an index of ``stamps_2``
    may appear more than once. Returns ``(i1, i2)``, int64 ``(M,)`` each, ``i1`` increasing.
    Vectorised equivalent of evo's ``sync.matching_time_indices`` (same float operations).
    """
    s1 = np.asarray(stamps_1, dtype=np.float64)
    s2 = np.asarray(stamps_2, dtype=np.float64) + offset_2
    if len(s1) == 0 or len(s2) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    in_range = (s1 >= s2[0] - max_diff) & (s1 <= s2[-1] + max_diff)
    upper = np.minimum(np.searchsorted(s2, s1, side="right"), len(s2) - 1)
    diff_ub = s2[upper] - s1
    diff_lb = np.where(upper > 0, s1 - s2[np.maximum(upper - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    keep = in_range & (take_ub | take_lb)
    best = np.where(take_ub, upper, upper - 1)
    return np.flatnonzero(keep).astype(np.int64), best[keep].astype(np.int64)


def associate_trajectories(
    gt: Trajectory, est: Trajectory, *, max_diff: float = DEFAULT_MAX_DIFF, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Pose pairs of ``gt`` and ``est`` with (nearly) equal stamps, as evo associates them.

    The shorter trajectory (``est`` when both have as many poses) keeps each pose that has a pose
    of the other within ``max_diff`` seconds (inclusive), matched to the nearest one (earlier on a
    tie; may repeat). ``offset`` (seconds) is added to ``est``'s stamps.

    Returns ``(gt_indices, est_indices)``: int64 ``(M,)`` arrays, both non-decreasing.
    """
    _check_trajectory(gt, "ground-truth")
    _check_trajectory(est, "estimated")
    if not (math.isfinite(max_diff) and max_diff >= 0):
        raise ValueError(f"max_diff must be a finite number >= 0 seconds, got {max_diff}")
    if not math.isfinite(offset):
        raise ValueError(f"offset must be a finite number of seconds, got {offset}")
    if len(est) > len(gt):
        gi, ei = matching_time_indices(gt.stamps, est.stamps, max_diff=max_diff, offset_2=offset)
    else:
        # evo walks the estimate here and shifts the other side by -offset: same pairs but for
        # the rounding of the shifted stamps, which we reproduce.
        ei, gi = matching_time_indices(est.stamps, gt.stamps, max_diff=max_diff, offset_2=-offset)
    return gi, ei


def _associate_enough(
    gt: Trajectory, est: Trajectory, max_diff: float, offset: float
) -> tuple[np.ndarray, np.ndarray]:
    gi, ei = associate_trajectories(gt, est, max_diff=max_diff, offset=offset)
    if len(gi) < MIN_ASSOCIATED_POSES:
        raise AssociationError(
            f"{_name(est, 'estimated')}: only {len(gi)} of its {len(est)} poses associate with "
            f"{_name(gt, 'ground-truth')} ({len(gt)} poses) with max_diff {max_diff:g} s and "
            f"offset {offset:g} s; need at least {MIN_ASSOCIATED_POSES} "
            f"(do the stamps overlap? try --offset or a larger --max-diff)"
        )
    return gi, ei


# --------------------------------------------------------------------------- alignment


def align_umeyama(
    src_xyz: np.ndarray, dst_xyz: np.ndarray, *, with_scale: bool
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity (Umeyama 1991) taking ``src_xyz`` onto ``dst_xyz``.

    ``src_xyz``, ``dst_xyz``: ``(N, 3)`` corresponding points (metres). Returns ``(R, t, s)`` with
    ``R`` ``(3, 3)`` a rotation, ``t`` ``(3,)`` metres and ``s`` the scale (1.0 unless
    ``with_scale``) minimising ``Σ‖dst - (s R src + t)‖²``. Raises :class:`AlignmentError` when
    the points do not fix a rotation (fewer than two non-zero singular values of the
    cross-covariance, evo's criterion: collinear or identical points).
    """
    x = np.asarray(src_xyz, dtype=np.float64)
    y = np.asarray(dst_xyz, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise ValueError(f"need two (N, 3) point arrays, got {x.shape} and {y.shape}")
    n = len(x)
    mean_x = x.mean(axis=0)
    mean_y = y.mean(axis=0)
    xc = x - mean_x
    yc = y - mean_y
    sigma_x = 1.0 / n * np.linalg.norm(xc) ** 2
    cov = (yc.T @ xc) / n
    u, d, vt = np.linalg.svd(cov)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < 2:
        raise AlignmentError(
            f"degenerate point sets ({n} points): collinear or identical positions do not "
            "determine a rotation"
        )
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        sign[2, 2] = -1.0  # a reflection would fit better: take the best proper rotation
    r = u @ sign @ vt
    s = float(np.trace(np.diag(d) @ sign) / sigma_x) if with_scale else 1.0
    t = mean_y - s * (r @ mean_x)
    return r, t, s


# --------------------------------------------------------------------------- ATE


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error (translation) over the associated poses.

    ``stamps`` (N,) the estimate's stamps (seconds, without offset); ``errors`` (N,) metres;
    ``gt_positions`` (N, 3) and ``est_positions`` (N, 3, after alignment) metres;
    ``transform`` (4, 4) the similarity ``[[s R, t], [0, 1]]`` applied to the estimate;
    ``scale`` its ``s``; ``gt_indices`` / ``est_indices`` (N,) rows of the input trajectories.
    """

    stats: ErrorStats
    stamps: np.ndarray
    errors: np.ndarray
    gt_positions: np.ndarray
    est_positions: np.ndarray
    transform: np.ndarray
    scale: float
    align: str
    gt_indices: np.ndarray
    est_indices: np.ndarray

    def as_dict(self) -> dict[str, float | int]:
        """The statistics as ``{"rmse", "mean", "median", "std", "min", "max", "pairs"}``."""
        return self.stats.as_dict()


def ate(
    gt: Trajectory,
    est: Trajectory,
    *,
    max_diff: float = DEFAULT_MAX_DIFF,
    offset: float = 0.0,
    align: str = "se3",
) -> AteResult:
    """Absolute trajectory error of ``est`` against ``gt`` (evo's ``evo_ape`` translation part).

    Associates by stamp (``max_diff``, ``offset`` in seconds; see :func:`associate_trajectories`),
    aligns the estimate's positions onto the ground truth (``align``: ``"se3"`` rigid,
    ``"sim3"`` with scale, ``"none"``), and measures position distances in metres.
    Raises :class:`AssociationError` for fewer than ``MIN_ASSOCIATED_POSES`` associated poses and
    :class:`AlignmentError` when the positions cannot be aligned.
    """
    if align not in ALIGNMENTS:
        raise ValueError(f"align must be one of {', '.join(ALIGNMENTS)}, got {align!r}")
    gi, ei = _associate_enough(gt, est, max_diff, offset)
    ref = gt.positions[gi]
    pos = est.positions[ei]
    if align == "none":
        r, t, s = np.eye(3), np.zeros(3), 1.0
    else:
        try:
            r, t, s = align_umeyama(pos, ref, with_scale=align == "sim3")
        except AlignmentError as err:
            raise AlignmentError(
                f"{_name(est, 'estimated')}: cannot {align}-align to {_name(gt, 'ground-truth')}: "
                f"{err} (use align 'none')"
            ) from None
    aligned = (s * pos) @ r.T + t
    errors = np.linalg.norm(aligned - ref, axis=1)
    transform = np.eye(4)
    transform[:3, :3] = s * r
    transform[:3, 3] = t
    return AteResult(
        stats=ErrorStats.from_errors(errors),
        stamps=est.stamps[ei],
        errors=errors,
        gt_positions=ref,
        est_positions=aligned,
        transform=transform,
        scale=s,
        align=align,
        gt_indices=gi,
        est_indices=ei,
    )


@dataclass(frozen=True)
class AteBands:
    """An ATE split by how fast its error changes: ``slow`` the RMSE of the error vectors
    averaged over ``window`` seconds around each pose (drift and bias that persist across
    frames: what a keyframe back end can correct), ``fast`` the RMSE of what is left (per-frame
    jitter of the tracker, which ORB-SLAM2's back end never touches: frames outside keyframes
    keep their tracked pose relative to their reference keyframe). ``rmse`` is the whole ATE;
    the two parts' squares add up to about its square. Metres."""

    window: float
    rmse: float
    slow: float
    fast: float

    def as_dict(self) -> dict[str, float]:
        return {"window_s": self.window, "rmse": self.rmse, "slow": self.slow, "fast": self.fast}


def ate_bands(result: AteResult, window: float = 0.5) -> AteBands:
    """:class:`AteBands` of an :func:`ate` result: each aligned error vector averaged with those
    of the poses within ``window / 2`` seconds of it (a moving average in time) is its slow
    part, the rest its fast part."""
    if not window > 0:
        raise ValueError(f"window must be > 0 s, got {window}")
    t = np.asarray(result.stamps, np.float64)
    e = result.est_positions - result.gt_positions
    lo = np.searchsorted(t, t - window / 2, side="left")
    hi = np.searchsorted(t, t + window / 2, side="right")
    csum = np.vstack([np.zeros((1, 3)), np.cumsum(e, axis=0)])
    slow = (csum[hi] - csum[lo]) / (hi - lo)[:, None]

    def rms(x: np.ndarray) -> float:
        return math.sqrt(float(np.mean(np.sum(x**2, axis=1))))

    return AteBands(window, rms(e), rms(slow), rms(e - slow))


# --------------------------------------------------------------------------- RPE


@dataclass(frozen=True)
class RpeResult:
    """Relative pose error over pose pairs ``delta`` apart (frames or seconds).

    ``trans`` statistics in metres, ``rot_deg`` in degrees, over ``pairs`` pairs. Per pair:
    ``stamps`` (M,) the estimate's stamp of the pair's first pose (seconds), ``intervals`` (M,)
    the pair's interval on the estimate's clock (seconds), ``trans_errors`` (M,) metres,
    ``rot_errors_deg`` (M,) degrees. ``skipped``: ``unit="seconds"`` start poses whose partner time
    lies inside the trajectory but has no associated pose within tolerance (always 0 for frames).
    """

    trans: ErrorStats
    rot_deg: ErrorStats
    pairs: int
    delta: float
    unit: str
    skipped: int
    stamps: np.ndarray
    intervals: np.ndarray
    trans_errors: np.ndarray
    rot_errors_deg: np.ndarray

    def as_dict(self) -> dict[str, dict[str, float | int]]:
        """``{"trans": {...}, "rot_deg": {...}}`` with :meth:`ErrorStats.as_dict` values."""
        return {"trans": self.trans.as_dict(), "rot_deg": self.rot_deg.as_dict()}


def _pairs_by_frames(n: int, delta: int) -> tuple[np.ndarray, np.ndarray]:
    starts = np.arange(0, n, delta, dtype=np.int64)
    return starts[:-1], starts[1:]


def _pairs_by_seconds(
    stamps: np.ndarray, delta: float, tol: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """Pairs ``(i, j)``: ``j`` the pose whose stamp is nearest ``stamps[i] + delta`` (earlier on a
    tie), kept if ``j > i`` and ``|stamps[j] - stamps[i] - delta| <= tol``. Also returns how many
    start poses were skipped although their target time lies within the stamps' span."""
    n = len(stamps)
    target = stamps + delta
    upper = np.minimum(np.searchsorted(stamps, target, side="left"), n - 1)
    lower = np.maximum(upper - 1, 0)
    nearer_upper = np.abs(stamps[upper] - target) < np.abs(stamps[lower] - target)
    j = np.where(nearer_upper, upper, lower)
    i = np.arange(n, dtype=np.int64)
    ok = (j > i) & (np.abs(stamps[j] - stamps[i] - delta) <= tol)
    skipped = int(np.count_nonzero(~ok & (target <= stamps[-1])))
    return i[ok], j[ok].astype(np.int64), skipped


def _rotation_angles(r: np.ndarray) -> np.ndarray:
    """Rotation angles (radians, in [0, π]) of ``(M, 3, 3)`` rotations.

    atan2 of the skew and trace parts stays accurate near 0 and π, unlike arccos of the trace.
    """
    skew = np.stack(
        [r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1
    )
    trace = r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=1), 0.5 * (trace - 1.0))


def rpe(
    gt: Trajectory,
    est: Trajectory,
    *,
    delta: float = 1,
    unit: str = "frames",
    max_diff: float = DEFAULT_MAX_DIFF,
    offset: float = 0.0,
) -> RpeResult:
    """Relative pose error of ``est`` against ``gt`` (evo's ``evo_rpe``, consecutive pairs).

    Associates by stamp like :func:`ate`, then compares the relative motions over pose pairs
    ``delta`` apart among the associated poses: ``unit="frames"`` (``delta`` a positive integer)
    takes pairs ``(0, d), (d, 2d), …``; ``unit="seconds"`` (``delta > 0``) pairs every pose with
    the one nearest ``delta`` seconds later (see the module docstring). No alignment is needed:
    RPE does not change under a rigid motion of either trajectory.
    Raises :class:`AssociationError` when too few poses associate or no pair is found.
    """
    if unit not in DELTA_UNITS:
        raise ValueError(f"unit must be one of {', '.join(DELTA_UNITS)}, got {unit!r}")
    if not (math.isfinite(delta) and delta > 0):
        raise ValueError(f"delta must be a positive number, got {delta}")
    if unit == "frames" and float(delta) != int(delta):
        raise ValueError(f"delta must be a whole number of frames, got {delta}")
    gi, ei = _associate_enough(gt, est, max_diff, offset)
    est_stamps = est.stamps[ei]
    skipped = 0
    if unit == "frames":
        i, j = _pairs_by_frames(len(gi), int(delta))
    else:
        tol = SECONDS_DELTA_REL_TOL * delta
        i, j, skipped = _pairs_by_seconds(est_stamps, float(delta), tol)
    if len(i) == 0:
        raise NoPairsError(
            f"{_name(est, 'estimated')}: no pose pairs {delta:g} {unit} apart among the "
            f"{len(gi)} poses associated with {_name(gt, 'ground-truth')} "
            f"(max_diff {max_diff:g} s, offset {offset:g} s); use a delta shorter than the "
            f"trajectory and, in seconds, no finer than its sampling"
        )
    rq = quat_to_matrix(gt.quaternions[gi])
    rp = quat_to_matrix(est.quaternions[ei])
    tq = gt.positions[gi]
    tp = est.positions[ei]

    def relative(r: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ri_t = np.swapaxes(r[i], 1, 2)
        return ri_t @ r[j], (ri_t @ (t[j] - t[i])[:, :, None])[:, :, 0]

    rq_rel, tq_rel = relative(rq, tq)
    rp_rel, tp_rel = relative(rp, tp)
    # E = Q_rel⁻¹ P_rel: rotation Rq_relᵀ Rp_rel, translation Rq_relᵀ (tp_rel - tq_rel), whose norm
    # is that of (tp_rel - tq_rel).
    trans_errors = np.linalg.norm(tp_rel - tq_rel, axis=1)
    rot_errors = np.rad2deg(_rotation_angles(np.swapaxes(rq_rel, 1, 2) @ rp_rel))
    return RpeResult(
        trans=ErrorStats.from_errors(trans_errors),
        rot_deg=ErrorStats.from_errors(rot_errors),
        pairs=len(i),
        delta=float(delta),
        unit=unit,
        skipped=skipped,
        stamps=est_stamps[i],
        intervals=est_stamps[j] - est_stamps[i],
        trans_errors=trans_errors,
        rot_errors_deg=rot_errors,
    )

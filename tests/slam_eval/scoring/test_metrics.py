"""ATE / RPE: known answers on random SE(3) trajectories, association rules, and agreement with evo."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from evo_helpers import evo_ape

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.tum_io import Trajectory, quat_to_matrix
from uss_slam.slam_eval.scoring.metrics import (
    SECONDS_DELTA_REL_TOL,
    AlignmentError,
    AssociationError,
    ErrorStats,
    align_umeyama,
    associate_trajectories,
    ate,
    ate_bands,
    matching_time_indices,
    rpe,
)

if sys.version_info >= (3, 11):
    # evo is in the dev extra for Python >= 3.11 (evo's own floor): a missing evo is a broken
    # install there, so import it outright rather than skipping.
    from evo import main_rpe
    from evo.core import lie_algebra, sync
    from evo.core.metrics import PoseRelation, Unit
    from evo.core.trajectory import PoseTrajectory3D

    HAVE_EVO = True
else:  # pragma: no cover
    HAVE_EVO = False

needs_evo = pytest.mark.skipif(not HAVE_EVO, reason="evo needs Python >= 3.11")

TOL = 1e-9  # metres / degrees: agreement with evo


# --------------------------------------------------------------------------- helpers


def unit_quaternions(n: int, rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def random_se3(rng: np.random.Generator, translation: float = 5.0) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = quat_to_matrix(unit_quaternions(1, rng))[0]
    t[:3, 3] = rng.uniform(-translation, translation, 3)
    return t


def random_trajectory(
    n: int,
    rng: np.random.Generator,
    *,
    start: float = 0.0,
    period: float = 0.01,
    jitter: float = 0.0,
    path: Path | None = None,
) -> Trajectory:
    """A random walk with random orientations; stamps ``period`` apart, ± ``jitter`` of it."""
    steps = period * rng.uniform(1 - jitter, 1 + jitter, n) if jitter else np.full(n, period)
    stamps = start + np.cumsum(steps)
    positions = np.cumsum(rng.normal(0.0, 0.05, (n, 3)), axis=0)
    return Trajectory(stamps, positions, unit_quaternions(n, rng), path=path)


def transformed(traj: Trajectory, t: np.ndarray, scale: float = 1.0) -> Trajectory:
    """``t · pose`` for each pose, positions then multiplied by ``scale``."""
    poses = t[None] @ traj.matrices()
    poses[:, :3, 3] *= scale
    moved = Trajectory.from_matrices(traj.stamps, poses)
    return moved


def perturbed(traj: Trajectory, rng: np.random.Generator, sigma: float, angle: float) -> Trajectory:
    """Positions plus N(0, sigma²) noise, orientations turned by up to ``angle`` radians."""
    axis = rng.normal(size=(len(traj), 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    half = rng.uniform(0, angle, len(traj))[:, None] / 2
    dq = np.hstack([axis * np.sin(half), np.cos(half)])
    r = quat_to_matrix(traj.quaternions) @ quat_to_matrix(dq)
    poses = traj.matrices()
    poses[:, :3, :3] = r
    poses[:, :3, 3] += rng.normal(0.0, sigma, (len(traj), 3))
    return Trajectory.from_matrices(traj.stamps, poses)


def stats_of(result_stats: ErrorStats) -> np.ndarray:
    d = result_stats.as_dict()
    return np.array([d[k] for k in ("rmse", "mean", "median", "std", "min", "max")])


def to_evo(traj: Trajectory) -> PoseTrajectory3D:
    return PoseTrajectory3D(
        positions_xyz=traj.positions.copy(),
        orientations_quat_wxyz=np.roll(traj.quaternions, 1, axis=1),
        timestamps=traj.stamps.copy(),
    )


def evo_stats(result) -> np.ndarray:
    s = result.stats
    return np.array([s["rmse"], s["mean"], s["median"], s["std"], s["min"], s["max"]])


# --------------------------------------------------------------------------- statistics


def test_error_stats_are_population_statistics() -> None:
    e = np.array([3.0, 1.0, 2.0, 10.0])
    stats = ErrorStats.from_errors(e)
    assert stats.as_dict() == {
        "rmse": np.sqrt((9 + 1 + 4 + 100) / 4),
        "mean": 4.0,
        "median": 2.5,
        "std": np.sqrt(((3 - 4) ** 2 + (1 - 4) ** 2 + (2 - 4) ** 2 + (10 - 4) ** 2) / 4),
        "min": 1.0,
        "max": 10.0,
        "pairs": 4,
    }
    assert list(stats.as_dict()) == ["rmse", "mean", "median", "std", "min", "max", "pairs"]
    with pytest.raises(ValueError):
        ErrorStats.from_errors(np.zeros(0))


# --------------------------------------------------------------------------- known answers


@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
def test_identical_trajectories_have_zero_error(align: str) -> None:
    gt = random_trajectory(200, np.random.default_rng(0))
    result = ate(gt, gt, align=align)
    assert result.stats.pairs == 200
    np.testing.assert_allclose(stats_of(result.stats), 0.0, atol=1e-12)
    np.testing.assert_allclose(result.transform, np.eye(4), atol=1e-12)
    assert result.scale == pytest.approx(1.0, abs=1e-12)
    relative = rpe(gt, gt, delta=3)
    np.testing.assert_allclose(stats_of(relative.trans), 0.0, atol=1e-12)
    np.testing.assert_allclose(stats_of(relative.rot_deg), 0.0, atol=1e-6)  # acos-free: exact
    assert relative.pairs == len(range(0, 200, 3)) - 1


def test_rigidly_moved_copy_is_zero_after_se3_alignment_only() -> None:
    rng = np.random.default_rng(1)
    gt = random_trajectory(300, rng)
    move = random_se3(rng)
    est = transformed(gt, move)
    for align in ("se3", "sim3"):
        result = ate(gt, est, align=align)
        assert result.stats.max < 1e-9, align
        assert result.scale == pytest.approx(1.0, abs=1e-9)
        np.testing.assert_allclose(result.transform, np.linalg.inv(move), atol=1e-9)
        np.testing.assert_allclose(result.est_positions, gt.positions, atol=1e-9)
    raw = ate(gt, est, align="none")
    np.testing.assert_allclose(
        raw.errors, np.linalg.norm(est.positions - gt.positions, axis=1), rtol=0, atol=1e-12
    )
    assert raw.stats.min > 1e-3
    # RPE compares relative motions: a rigid motion of the whole estimate changes nothing.
    relative = rpe(gt, est, delta=2)
    assert relative.trans.max < 1e-9
    assert relative.rot_deg.max < 1e-6


def test_scaled_copy_is_zero_after_sim3_but_not_se3() -> None:
    rng = np.random.default_rng(2)
    gt = random_trajectory(250, rng)
    est = transformed(gt, random_se3(rng), scale=2.5)
    sim3 = ate(gt, est, align="sim3")
    assert sim3.stats.max < 1e-9
    assert sim3.scale == pytest.approx(1 / 2.5, rel=1e-12)
    np.testing.assert_allclose(np.linalg.det(sim3.transform[:3, :3]), (1 / 2.5) ** 3, rtol=1e-12)
    se3 = ate(gt, est, align="se3")
    assert se3.scale == 1.0
    assert se3.stats.rmse > 0.01


def test_injected_noise_gives_exactly_its_statistics() -> None:
    """Noise orthogonal to (1, positions) leaves the SE(3) optimum at the identity, so the ATE after
    alignment is exactly the norm of each injected offset."""
    rng = np.random.default_rng(3)
    gt = random_trajectory(400, rng)
    noise = rng.normal(0.0, 0.02, (400, 3))
    basis = np.hstack([np.ones((400, 1)), gt.positions - gt.positions.mean(axis=0)])
    noise -= basis @ np.linalg.lstsq(basis, noise, rcond=None)[0]
    est = Trajectory(gt.stamps, gt.positions + noise, gt.quaternions)
    norms = np.linalg.norm(noise, axis=1)
    expected = np.array(
        [
            np.sqrt(np.mean(norms**2)),
            norms.mean(),
            np.median(norms),
            norms.std(ddof=0),
            norms.min(),
            norms.max(),
        ]
    )
    for align in ("se3", "none"):
        result = ate(gt, est, align=align)
        np.testing.assert_allclose(result.errors, norms, rtol=0, atol=1e-12)
        np.testing.assert_allclose(stats_of(result.stats), expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(result.transform, np.eye(4), atol=1e-12)
    assert abs(expected[3] - norms.std(ddof=1)) > 1e-6  # the population std is the one checked


def test_umeyama_recovers_a_similarity_and_rejects_collinear_points() -> None:
    rng = np.random.default_rng(4)
    src = rng.normal(size=(50, 3))
    move = random_se3(rng)
    dst = 0.7 * src @ move[:3, :3].T + move[:3, 3]
    r, t, s = align_umeyama(src, dst, with_scale=True)
    np.testing.assert_allclose(r, move[:3, :3], atol=1e-12)
    np.testing.assert_allclose(t, move[:3, 3], atol=1e-12)
    assert s == pytest.approx(0.7, rel=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    # A mirrored point set: the best *proper* rotation, never a reflection.
    r, _, _ = align_umeyama(src, src * np.array([1.0, 1.0, -1.0]), with_scale=False)
    assert np.linalg.det(r) == pytest.approx(1.0)
    line = np.outer(np.linspace(0, 1, 10), [1.0, 2.0, 3.0])
    with pytest.raises(AlignmentError):
        align_umeyama(line, line, with_scale=False)


# --------------------------------------------------------------------------- association


def traj_at(stamps, path: str | None = None) -> Trajectory:
    stamps = np.asarray(stamps, dtype=np.float64)
    n = len(stamps)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    positions = np.column_stack([stamps, np.sin(stamps), np.cos(3 * stamps)])
    return Trajectory(stamps, positions, q, path=None if path is None else Path(path))


def test_association_nearest_inclusive_ties_earlier_and_repeats() -> None:
    # Dyadic stamps make every difference exact, so the boundary cases are really on the boundary.
    gt = traj_at(np.arange(20) * 0.25)  # 0, 0.25, ..., 4.75
    gt = traj_at(np.delete(gt.stamps, [12, 13]))  # no 3.0, 3.25
    est = traj_at([0.0625, 0.375, 1.125, 1.5, 1.5625, 3.1875])
    gi, ei = associate_trajectories(gt, est, max_diff=0.125)
    # 0.0625 -> 0 (nearest); 0.375 ties 0.25/0.5 -> 0.25 (earlier); 1.125 ties -> 1.0, at exactly
    # max_diff (inclusive); 1.5 and 1.5625 both -> 1.5 (a gt pose may repeat); 3.1875 is 0.3125
    # from its nearest: dropped.
    np.testing.assert_array_equal(ei, [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(gi, [0, 1, 4, 6, 6])


def test_association_walks_the_shorter_trajectory_and_applies_offset_to_est() -> None:
    gt = traj_at(np.arange(4) * 1.0 + 10.0)  # 10, 11, 12, 13: shorter, walked
    est = traj_at(np.arange(60) * 0.125 + 8.5625)  # every stamp 0.0625 s off the gt grid
    gi, ei = associate_trajectories(gt, est, max_diff=0.01)
    assert len(gi) == 0
    gi, ei = associate_trajectories(gt, est, max_diff=0.01, offset=0.4375)
    np.testing.assert_array_equal(gi, [0, 1, 2, 3])
    np.testing.assert_array_equal(est.stamps[ei] + 0.4375, gt.stamps)
    # Equal lengths: the estimate is walked, and gaps in it simply drop poses.
    gt = traj_at(np.arange(10) * 0.5)
    est = traj_at(np.r_[np.arange(4) * 0.5, np.arange(7, 13) * 0.5] + 0.01)
    gi, ei = associate_trajectories(gt, est, max_diff=0.02)
    np.testing.assert_array_equal(gi, [0, 1, 2, 3, 7, 8, 9])
    np.testing.assert_array_equal(ei, [0, 1, 2, 3, 4, 5, 6])
    # Equal lengths where the walked side matters: walking gt would pair both 0.0 and 0.5 with
    # est's 0.375; walking est pairs 0.375 with its nearest, 0.5, only.
    gi, ei = associate_trajectories(
        traj_at([0.0, 0.5, 5.0, 6.0]), traj_at([0.375, 10.0, 11.0, 12.0]), max_diff=0.5
    )
    np.testing.assert_array_equal(gi, [1])
    np.testing.assert_array_equal(ei, [0])


@needs_evo
def test_association_matches_evo_on_quantised_jittered_stamps() -> None:
    """Stamps on a 1/64 s grid produce many exact ties and boundary hits."""
    rng = np.random.default_rng(5)
    for trial in range(30):
        n_gt, n_est = rng.integers(5, 80, 2)
        if trial % 3 == 0:
            n_est = n_gt  # equal lengths: evo walks the estimate
        gt = traj_at(np.sort(rng.choice(400, n_gt, replace=False)) / 64.0)
        est = traj_at(np.sort(rng.choice(400, n_est, replace=False)) / 64.0)
        max_diff = float(rng.choice([0.0, 1 / 64, 2 / 64, 0.02, 0.1]))
        offset = float(rng.choice([0.0, 1 / 64, -3 / 64, 0.013]))
        gi, ei = associate_trajectories(gt, est, max_diff=max_diff, offset=offset)
        try:
            ref, sync_est = sync.associate_trajectories(
                to_evo(gt), to_evo(est), max_diff=max_diff, offset_2=offset
            )
        except sync.SyncException:
            assert len(gi) == 0, trial
            continue
        np.testing.assert_array_equal(gt.stamps[gi], ref.timestamps)
        np.testing.assert_array_equal(est.stamps[ei], sync_est.timestamps)
        i1, i2 = sync.matching_time_indices(gt.stamps, est.stamps, max_diff, offset)
        j1, j2 = matching_time_indices(gt.stamps, est.stamps, max_diff=max_diff, offset_2=offset)
        np.testing.assert_array_equal(j1, i1)
        np.testing.assert_array_equal(j2, i2)


def test_fewer_than_three_associated_poses_names_both_files() -> None:
    gt = traj_at(np.arange(10) * 0.1, "run/groundtruth.txt")
    est = traj_at([0.0, 0.5, 5.0, 6.0], "run/trajectory.txt")
    with pytest.raises(AssociationError) as info:
        ate(gt, est, max_diff=0.02, offset=0.0)
    message = str(info.value)
    assert "run/trajectory.txt" in message and "run/groundtruth.txt" in message
    assert "only 2 of its 4 poses" in message and "max_diff 0.02 s" in message
    assert isinstance(info.value, UssSlamError)
    with pytest.raises(AssociationError):
        rpe(gt, est)


def test_degenerate_estimate_is_an_error_naming_the_files_unless_not_aligned() -> None:
    gt = traj_at(np.arange(10) * 0.1, "gt.txt")
    frozen = Trajectory(gt.stamps, np.zeros((10, 3)), gt.quaternions, path=Path("est.txt"))
    with pytest.raises(AlignmentError, match=r"est\.txt: cannot se3-align to gt\.txt"):
        ate(gt, frozen)
    result = ate(gt, frozen, align="none")
    np.testing.assert_allclose(result.errors, np.linalg.norm(gt.positions, axis=1))


def test_in_memory_trajectories_are_validated() -> None:
    gt = traj_at(np.arange(10) * 0.1)
    shuffled = traj_at(np.array([0.0, 0.2, 0.1, 0.3]))
    with pytest.raises(DataFormatError, match="strictly increase"):
        ate(gt, shuffled)
    empty = Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)), path=Path("e.txt"))
    with pytest.raises(DataFormatError, match=r"e\.txt: no poses"):
        ate(gt, empty)
    with pytest.raises(ValueError, match="align"):
        ate(gt, gt, align="se2")
    with pytest.raises(ValueError, match="whole number"):
        rpe(gt, gt, delta=1.5)
    with pytest.raises(ValueError, match="unit"):
        rpe(gt, gt, unit="metres")


# --------------------------------------------------------------------------- RPE


def test_rpe_frames_takes_consecutive_pairs_delta_apart() -> None:
    rng = np.random.default_rng(6)
    gt = random_trajectory(101, rng)
    result = rpe(gt, perturbed(gt, rng, 0.01, 0.02), delta=10)
    assert result.pairs == 10  # (0, 10), (10, 20), ..., (90, 100)
    np.testing.assert_allclose(result.stamps, gt.stamps[0:100:10])
    np.testing.assert_allclose(result.intervals, 0.1)
    assert result.skipped == 0


def test_rpe_seconds_known_drift() -> None:
    """Same orientations, positions drifting at v m/s: each pair's error is |v| times its
    interval, whatever the rotations, and the rotation error is zero."""
    rng = np.random.default_rng(7)
    gt = random_trajectory(500, rng, period=0.012)
    v = np.array([0.03, -0.04, 0.12])  # |v| = 0.13 m/s
    est = Trajectory(gt.stamps, gt.positions + np.outer(gt.stamps, v), gt.quaternions)
    result = rpe(gt, est, delta=0.5, unit="seconds")
    # Poses 0..457 pair with the one 42 frames (0.504 s) later; in the tail 458..461 the nearest
    # partner is the last pose, 37..41 frames later (within 10% of 0.5 s); 462.. have none.
    np.testing.assert_allclose(
        result.intervals, np.r_[np.full(458, 42), 41 - np.arange(4)] * 0.012, rtol=1e-9
    )
    assert result.pairs == 462 and result.skipped == 0
    np.testing.assert_allclose(result.trans_errors, 0.13 * result.intervals, rtol=1e-9)
    assert result.rot_deg.max < 1e-6
    expected = 0.13 * result.intervals
    assert result.trans.rmse == pytest.approx(np.sqrt(np.mean(expected**2)), rel=1e-9)


def test_rpe_seconds_partner_is_nearest_earlier_on_ties() -> None:
    # No pose at 1.0: 0.9375 and 1.0625 are equally near (and within 10% of 1 s): the earlier wins.
    traj = traj_at([0.0, 0.9375, 1.0625, 2.0, 3.0, 4.0])
    result = rpe(traj, traj, delta=1.0, unit="seconds")
    np.testing.assert_array_equal(result.stamps, [0.0, 0.9375, 1.0625, 2.0, 3.0])
    np.testing.assert_array_equal(result.intervals, [0.9375, 1.0625, 0.9375, 1.0, 1.0])


def brute_force_rpe_seconds(gt: Trajectory, est: Trajectory, delta: float, max_diff: float):
    """An independent, loop-by-loop reading of the documented ``unit="seconds"`` rule."""
    ref, sync_est = sync.associate_trajectories(to_evo(gt), to_evo(est), max_diff=max_diff)
    stamps = sync_est.timestamps
    tol = SECONDS_DELTA_REL_TOL * delta
    trans, rot, skipped = [], [], 0
    for i in range(len(stamps)):
        target = stamps[i] + delta
        gaps = [abs(s - target) for s in stamps]
        j = gaps.index(min(gaps))  # first of equally near ones = the earlier
        if j > i and abs(stamps[j] - stamps[i] - delta) <= tol:
            q_rel = np.linalg.inv(ref.poses_se3[i]) @ ref.poses_se3[j]
            p_rel = np.linalg.inv(sync_est.poses_se3[i]) @ sync_est.poses_se3[j]
            e = np.linalg.inv(q_rel) @ p_rel
            trans.append(np.linalg.norm(e[:3, 3]))
            rot.append(lie_algebra.so3_log_angle(e[:3, :3], degrees=True))
        elif target <= stamps[-1]:
            skipped += 1
    return np.array(trans), np.array(rot), skipped


@needs_evo
def test_rpe_seconds_matches_an_independent_derivation_with_gaps() -> None:
    rng = np.random.default_rng(8)
    gt = random_trajectory(600, rng, period=0.01, jitter=0.3)
    est_full = perturbed(gt, rng, 0.01, 0.03)
    keep = (gt.stamps < 1.5) | (gt.stamps > 2.7)  # a 1.2 s gap in the estimate
    keep &= rng.uniform(size=600) > 0.3  # and irregular sampling
    est = Trajectory(
        est_full.stamps[keep] + rng.uniform(-0.004, 0.004, keep.sum()),
        est_full.positions[keep],
        est_full.quaternions[keep],
    )
    for delta in (0.05, 0.5, 1.0):
        result = rpe(gt, est, delta=delta, unit="seconds")
        trans, rot, skipped = brute_force_rpe_seconds(gt, est, delta, 0.02)
        assert result.pairs == len(trans) and result.skipped == skipped > 0
        np.testing.assert_allclose(result.trans_errors, trans, rtol=0, atol=TOL)
        np.testing.assert_allclose(result.rot_errors_deg, rot, rtol=0, atol=TOL)
        tol = SECONDS_DELTA_REL_TOL * delta
        assert np.all(np.abs(result.intervals - delta) <= tol)
    with pytest.raises(AssociationError, match="no pose pairs"):
        rpe(gt, est, delta=0.001, unit="seconds")


# --------------------------------------------------------------------------- agreement with evo


def independent_pair(rng: np.random.Generator, noisy: bool) -> tuple[Trajectory, Trajectory]:
    """Ground truth at ~100 Hz and an estimate at ~30 Hz, jittered stamps, different spans."""
    gt = random_trajectory(int(rng.integers(300, 500)), rng, start=100.0, jitter=0.5)
    n_est = int(rng.integers(60, 160))
    if noisy:
        # An estimate of the same motion: sample gt near 30 Hz, perturb, move rigidly, rescale.
        idx = np.unique(np.clip(np.cumsum(rng.integers(3, 5, n_est)), 0, len(gt) - 1))
        sub = Trajectory(
            gt.stamps[idx] + rng.uniform(-0.004, 0.004, len(idx)),  # keeps them increasing
            gt.positions[idx],
            gt.quaternions[idx],
        )
        est = transformed(perturbed(sub, rng, 0.02, 0.05), random_se3(rng), scale=1.3)
    else:
        est = random_trajectory(
            n_est, rng, start=100.0 + rng.uniform(-0.5, 0.5), period=0.033, jitter=0.6
        )
    return gt, est


@needs_evo
@pytest.mark.parametrize("noisy", [True, False], ids=["estimate", "independent"])
def test_ate_and_rpe_agree_with_evo(noisy: bool) -> None:
    rng = np.random.default_rng(9 if noisy else 10)
    for trial in range(4):
        gt, est = independent_pair(rng, noisy)
        offset = 0.0 if trial % 2 == 0 else float(rng.uniform(-0.01, 0.01))
        for align in ("se3", "sim3", "none"):
            ref, sync_est = sync.associate_trajectories(
                to_evo(gt), to_evo(est), max_diff=0.02, offset_2=offset
            )
            expected = evo_ape(ref, sync_est, align)
            ours = ate(gt, est, max_diff=0.02, offset=offset, align=align)
            assert ours.stats.pairs == len(expected.np_arrays["error_array"]) >= 20
            np.testing.assert_allclose(stats_of(ours.stats), evo_stats(expected), rtol=0, atol=TOL)
            np.testing.assert_allclose(
                ours.errors, expected.np_arrays["error_array"], rtol=0, atol=TOL
            )
            np.testing.assert_array_equal(ours.stamps, expected.np_arrays["timestamps"])
            if align != "none":
                np.testing.assert_allclose(
                    ours.transform,
                    expected.np_arrays["alignment_transformation_sim3"],
                    rtol=0,
                    atol=TOL,
                )
        for delta in (1, 4):
            ours = rpe(gt, est, delta=delta, max_diff=0.02, offset=offset)
            for relation, stats, errors in (
                (PoseRelation.translation_part, ours.trans, ours.trans_errors),
                (PoseRelation.rotation_angle_deg, ours.rot_deg, ours.rot_errors_deg),
            ):
                ref, sync_est = sync.associate_trajectories(
                    to_evo(gt), to_evo(est), max_diff=0.02, offset_2=offset
                )
                expected = main_rpe.rpe(
                    ref, sync_est, relation, delta=delta, delta_unit=Unit.frames, all_pairs=False
                )
                assert stats.pairs == len(expected.np_arrays["error_array"])
                np.testing.assert_allclose(stats_of(stats), evo_stats(expected), rtol=0, atol=TOL)
                np.testing.assert_allclose(
                    errors, expected.np_arrays["error_array"], rtol=0, atol=TOL
                )


def test_ate_bands_separate_slow_drift_from_per_frame_jitter() -> None:
    # 30 Hz for 20 s: a slow swing (period 10 s, 20 mm) plus alternating 5 mm per-frame jitter
    t = np.arange(600) / 30.0
    slow = 0.02 * np.sin(2 * np.pi * t / 10.0)
    jitter = 0.005 * (-1.0) ** np.arange(600)
    gt = Trajectory(t, np.c_[t, np.zeros((600, 2))], np.tile([0.0, 0.0, 0.0, 1.0], (600, 1)))
    est = Trajectory(t, gt.positions + np.c_[np.zeros(600), slow + jitter, np.zeros(600)],
                     gt.quaternions)  # fmt: skip
    result = ate(gt, est, align="none")
    bands = ate_bands(result, window=0.5)
    assert bands.rmse == pytest.approx(result.stats.rmse)
    # the moving average over 0.5 s keeps the swing (attenuated < 1%) and cancels the jitter
    # but for one frame in 15 (an odd count of alternating signs: 5 mm x 16/15 left)
    assert bands.slow == pytest.approx(0.02 / np.sqrt(2), rel=0.01)
    assert bands.fast == pytest.approx(0.005 * 16 / 15, rel=0.01)
    assert bands.slow**2 + bands.fast**2 == pytest.approx(bands.rmse**2, rel=0.02)
    assert ate_bands(ate(gt, gt, align="none")).rmse == 0.0
    with pytest.raises(ValueError, match="window must be > 0 s"):
        ate_bands(result, window=0.0)

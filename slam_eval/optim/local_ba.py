"""ORB-SLAM2's ``Optimizer::LocalBundleAdjustment`` with GTSAM factor graphs and
Levenberg–Marquardt, over the shared map (:class:`~..map.slam_map.SlamMap`): the bundle adjuster
local mapping (:mod:`..mapping.local_mapping`) runs after each new keyframe and loop closing
(:mod:`..mapping.loop_closing`) after a loop correction, and the GTSAM keys both use.

Local bundle adjustment of a new keyframe ``K``:

- **free**: ``K`` and its covisible keyframes (sharing at least ``covisibility`` = 15 good map
  points), and every good map point they observe;
- **fixed**: the keyframes that observe those points but are not covisible with ``K`` (they anchor
  the local map to the rest), and keyframe 0 (the gauge, as ORB-SLAM2);
- **factors**: one per observation. A keypoint with depth is a stereo observation
  ``(u, v, u_r = u - bf / z)`` (``GenericStereoFactor3D`` with ``Cal3_S2Stereo`` of baseline
  ``bf / fx``: the virtual stereo pair the tracker uses), one without depth a monocular ``(u, v)``
  (``GenericProjectionFactorCal3_S2``); noise of the keypoint level's sigma σ (the scale factor
  to the power of the level, in pixels), Huber kernel of width √7.815 (stereo) / √5.991
  (monocular), the 95% χ² quantiles;
- **depth noise** (``depth_noise``): ORB-SLAM2 gives ``u_r`` the same independent σ as ``u``,
  i.e. a disparity ``bf / z`` known to √2 σ — at 2 m with the TUM ``bf`` of 40 px that is a depth
  uncertainty of ±14 cm, so with the points free the depth constrains the keyframes little
  (on synthetic static_xyz, whose depth has exactly the noise below, it does a little worse
  than ``k = 0.0019``: 6.0 against 5.8 mm, median of 3 seeds at 320×240).
  A Kinect measures depth to ``σ_z ≈ k·z²`` (k ≈ 0.0019 m⁻¹ for the synthetic target style,
  after Nguyen et al.), i.e. a disparity to ``σ_d = bf·k`` at every distance, and ``u_r`` shares
  ``u``'s detection noise; with ``depth_noise = k`` > 0 the stereo factors get that covariance
  (``σ² [[1, 1, 0], [1, 1 + σ_d²/σ², 0], [0, 0, 1]]`` over ``(u_L, u_R, v)``), ``depth_noise = 0``
  is ORB-SLAM2's model; by default (None) ``k`` is the camera's declared noise (the
  synthetic target style declares its 0.0019 in ``intrinsics.yaml``), else 0, as for every real
  Kinect (:func:`~..mapping.local_mapping.depth_noise_of`). On a real hand-held Kinect the depth
  agrees with the multi-view geometry far less than ``k·z²`` says: after local BA on TUM ``freiburg1_rpy`` the
  disparity residuals have a robust sigma of 0.74 px against the 0.074 px of ``k = 0.0019`` (the
  depth image is taken ~10 ms before the colour image while the camera turns at ~1.5 rad/s, an
  ~8 px misregistration, plus edges and quantisation), and with that model local BA made the
  trajectory twice as bad (ATE 0.013 → 0.026 m, median of 3 repeats) where ORB-SLAM2's model
  improves it (0.0127 m); ``docs/slam.md``, "Local BA on real frames";
- **passes**: ``first_iterations`` LM iterations with the kernel; with ``second_iterations`` > 0
  (ORB-SLAM2's second pass) the observations whose χ² exceeds those quantiles (or that fall
  behind the camera) are then left out, the kernel is dropped, and ``second_iterations`` more;
  finally the observations still above the quantiles are erased from the map (a point left with
  one keyframe is marked bad). Local mapping's default is one pass of 2 iterations, no
  second pass (ORB-SLAM3's single pass has 10: :class:`~..mapping.local_mapping.LocalMappingConfig`).

Fixed keyframes are variables with a tight prior (σ = 1e-6 m / rad): GTSAM's hard
``NonlinearEquality`` constraint gives the same result but optimised about five times slower here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import repeat

import gtsam
import numpy as np

from ..geometry import invert
from ..map.observation import CHI2_MONO, CHI2_STEREO, chi2_per_observation, observations
from ..map.slam_map import SlamMap

FIXED_SIGMA = 1e-6
"""Prior sigma of fixed keyframes, metres / radians (effectively constant)."""


def pose_key(keyframe_id: int) -> int:
    """GTSAM key of a keyframe pose (``Pose3``, camera-to-world)."""
    return gtsam.symbol("x", int(keyframe_id))


def point_key(point_id: int) -> int:
    """GTSAM key of a map point (``Point3``, world metres)."""
    return gtsam.symbol("l", int(point_id))


_INDEX_BITS = 56
"""A GTSAM ``Symbol`` key is its character shifted left by 56 bits, or'ed with its index."""


def _symbols(char: str, ids: np.ndarray) -> list[int]:
    """``gtsam.symbol(char, i)`` of every ``i`` in ``ids``, computed at once (plain ints)."""
    ids = np.asarray(ids, np.int64)
    if ids.size and (ids.min() < 0 or ids.max() >= 1 << _INDEX_BITS):
        raise ValueError(f"GTSAM symbol '{char}': expected ids in [0, 2^56), got {ids.min()}..")
    return (ids.astype(np.uint64) | np.uint64(ord(char) << _INDEX_BITS)).tolist()


def pose_keys(keyframe_ids: np.ndarray) -> list[int]:
    """:func:`pose_key` of each of ``keyframe_ids``."""
    return _symbols("x", keyframe_ids)


def point_keys(point_ids: np.ndarray) -> list[int]:
    """:func:`point_key` of each of ``point_ids``."""
    return _symbols("l", point_ids)


@dataclass
class Adjustment:
    """Outcome of one bundle adjustment (the map is already updated).

    ``free`` / ``fixed`` keyframe ids, ``points`` ids of the optimised points, ``observations``
    factors of the first pass, ``outliers`` observations erased, ``error`` the graph error (half
    the sum of squared whitened residuals, with the kernel) before and after the first pass.
    """

    free: np.ndarray
    fixed: np.ndarray
    points: np.ndarray
    observations: int
    outliers: int
    error: tuple[float, float]
    iterations: int


@dataclass
class _Observations:
    """The observations of one problem, one row each."""

    point: np.ndarray
    keyframe: np.ndarray
    meas: np.ndarray  # (M, 3) u, v, u_r
    stereo: np.ndarray
    level: np.ndarray
    inv_sigma2: np.ndarray


class BundleAdjuster:
    """Builds and solves bundle-adjustment factor graphs over a :class:`SlamMap`.

    ``k`` (3, 3) camera matrix, ``bf`` fx × virtual baseline (pixels × metres), ``sigma2`` (L,)
    the pyramid levels' variances (the scale factor squared to the power of the level),
    ``depth_noise`` k of ``σ_z = k·z²`` (0 = ORB-SLAM2's model, see the module docstring).
    """

    def __init__(
        self, k: np.ndarray, bf: float, sigma2: np.ndarray, depth_noise: float = 0.0
    ) -> None:
        self.k = k
        self.bf = bf
        self.disparity_sigma = bf * depth_noise
        self.sigma2 = np.asarray(sigma2, np.float64)
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        self.stereo_calibration = gtsam.Cal3_S2Stereo(fx, fy, 0.0, cx, cy, bf / fx)
        self.mono_calibration = gtsam.Cal3_S2(fx, fy, 0.0, cx, cy)
        self._noise: dict[tuple[bool, int, bool], gtsam.noiseModel.Base] = {}
        self.fixed_noise = gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)

    def noise(self, stereo: bool, level: int, robust: bool) -> gtsam.noiseModel.Base:
        """Noise of a level's sigma (pixels), with ORB-SLAM2's Huber kernel."""
        key = (stereo, level, robust)
        if key not in self._noise:
            s2 = float(self.sigma2[level])
            if stereo and self.disparity_sigma > 0:
                d2 = self.disparity_sigma**2
                cov = np.array([[s2, s2, 0.0], [s2, s2 + d2, 0.0], [0.0, 0.0, s2]])
                base = gtsam.noiseModel.Gaussian.Covariance(cov)
            else:
                base = gtsam.noiseModel.Isotropic.Sigma(3 if stereo else 2, math.sqrt(s2))
            if robust:
                delta = math.sqrt(CHI2_STEREO if stereo else CHI2_MONO)
                base = gtsam.noiseModel.Robust.Create(
                    gtsam.noiseModel.mEstimator.Huber.Create(delta), base
                )
            self._noise[key] = base
        return self._noise[key]

    def _gather(self, slam_map: SlamMap, point_ids: np.ndarray) -> _Observations:
        point, keyframe, keypoint = slam_map.observations_of(point_ids)
        meas = np.zeros((len(point), 3))
        stereo = np.zeros(len(point), bool)
        level = np.zeros(len(point), np.int64)
        for k in np.unique(keyframe):
            sel = keyframe == k
            f = slam_map.keyframes[int(k)].features
            kp = keypoint[sel]
            meas[sel], stereo[sel] = observations(f.uv[kp], f.depth[kp], self.bf)
            level[sel] = f.octave[kp]
        return _Observations(point, keyframe, meas, stereo, level, 1.0 / self.sigma2[level])

    def _chi2(
        self, obs: _Observations, poses_wc: dict[int, np.ndarray], positions: np.ndarray, index
    ) -> np.ndarray:
        """``(M,)`` True where an observation passes ORB-SLAM2's χ² and in-front tests."""
        ids = sorted(poses_wc)
        table = np.stack([invert(poses_wc[i]) for i in ids])
        row = np.searchsorted(np.array(ids), obs.keyframe)
        e2, front = chi2_per_observation(
            self.k,
            self.bf,
            table[row],
            positions[index],
            obs.meas,
            obs.stereo,
            obs.inv_sigma2,
            self.disparity_sigma,
        )
        return front & (e2 < np.where(obs.stereo, CHI2_STEREO, CHI2_MONO))

    def _factors(
        self, obs: _Observations, rows: np.ndarray, robust: bool
    ) -> gtsam.NonlinearFactorGraph:
        """One factor per observation in ``rows``, in that order: a stereo factor ``(u, u_r, v)``
        for an observation with depth, else a monocular ``(u, v)``, with its level's noise.

        Keys, noise models and measurements are prepared for all rows at once, and the factors
        are made by ``map`` over them, so the per-factor Python work is the GTSAM calls alone
        (about 2,000 factors per optimisation, two optimisations per keyframe)."""
        graph = gtsam.NonlinearFactorGraph()
        is_stereo = obs.stereo[rows]
        levels = range(len(self.sigma2))
        stereo_rows, mono_rows = rows[is_stereo], rows[~is_stereo]
        u, v, ur = obs.meas[stereo_rows].T.tolist() if len(stereo_rows) else ([], [], [])
        stereo = map(
            gtsam.GenericStereoFactor3D,
            map(gtsam.StereoPoint2, u, ur, v),
            map([self.noise(True, lv, robust) for lv in levels].__getitem__,
                obs.level[stereo_rows].tolist()),
            pose_keys(obs.keyframe[stereo_rows]),
            point_keys(obs.point[stereo_rows]),
            repeat(self.stereo_calibration),
        )  # fmt: skip
        mono = map(
            gtsam.GenericProjectionFactorCal3_S2,
            list(np.ascontiguousarray(obs.meas[mono_rows, :2])),
            map([self.noise(False, lv, robust) for lv in levels].__getitem__,
                obs.level[mono_rows].tolist()),
            pose_keys(obs.keyframe[mono_rows]),
            point_keys(obs.point[mono_rows]),
            repeat(self.mono_calibration),
        )  # fmt: skip
        add = graph.add
        for with_depth in is_stereo.tolist():
            add(next(stereo) if with_depth else next(mono))
        return graph

    def _solve(
        self,
        obs: _Observations,
        use: np.ndarray,
        poses_wc: dict[int, np.ndarray],
        fixed: set[int],
        point_ids: np.ndarray,
        positions: np.ndarray,
        index: np.ndarray,
        robust: bool,
        iterations: int,
    ) -> tuple[dict[int, np.ndarray], np.ndarray, float, float, int]:
        """One LM run over the observations in ``use``; points that the used observations do not
        determine (a single monocular one) are left out, as are keyframes without observations."""
        per_point = np.bincount(index[use], minlength=len(point_ids))
        stereo_point = np.bincount(index[use & obs.stereo], minlength=len(point_ids)) > 0
        solvable = stereo_point | (per_point >= 2)
        use = use & solvable[index]
        graph = self._factors(obs, np.flatnonzero(use), robust)
        values = gtsam.Values()
        used_kfs = np.unique(obs.keyframe[use]).tolist()
        free_used = [k for k in used_kfs if k not in fixed]
        anchors = [k for k in used_kfs if k in fixed] or free_used[:1]
        for k in used_kfs:
            pose = gtsam.Pose3(poses_wc[k])
            values.insert(pose_key(k), pose)
            if k in anchors:
                graph.add(gtsam.PriorFactorPose3(pose_key(k), pose, self.fixed_noise))
        used_points = np.flatnonzero(np.bincount(index[use], minlength=len(point_ids)) > 0)
        keys = point_keys(point_ids[used_points])
        for key, position in zip(keys, positions[used_points], strict=True):
            values.insert(key, position)
        if graph.size() == 0:
            return poses_wc, positions, 0.0, 0.0, 0
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(int(iterations))
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        before = optimizer.error()  # the graph's error at the initial values, computed once
        result = optimizer.optimize()
        out_poses = dict(poses_wc)
        for k in free_used:
            out_poses[k] = result.atPose3(pose_key(k)).matrix()
        out_positions = positions.copy()
        out_positions[used_points] = gtsam.utilities.extractPoint3(result)
        return out_poses, out_positions, before, optimizer.error(), optimizer.iterations()

    def adjust(
        self,
        slam_map: SlamMap,
        free: np.ndarray,
        point_ids: np.ndarray,
        first_iterations: int = 5,
        second_iterations: int = 10,
    ) -> Adjustment:
        """Bundle-adjust keyframes ``free`` and points ``point_ids`` (sorted); every other
        keyframe observing those points is fixed, and so is keyframe 0 (the gauge). Updates the
        map (poses, positions, erased outlier observations); ``second_iterations = 0`` skips the
        second pass (the outliers are still erased). No points: nothing is changed."""
        if len(point_ids) == 0:  # nothing left to adjust (a late mask took every point out)
            none = np.zeros(0, np.int64)
            return Adjustment(none, none, point_ids, 0, 0, (0.0, 0.0), 0)
        obs = self._gather(slam_map, point_ids)
        involved = np.unique(obs.keyframe)
        fixed = set(int(k) for k in np.setdiff1d(involved, free))
        if 0 in involved:
            fixed.add(0)
        poses = {int(k): slam_map.keyframes[int(k)].pose_wc.copy() for k in involved}
        positions = slam_map.points.position.view[point_ids].copy()
        index = np.searchsorted(point_ids, obs.point)
        use = np.ones(len(obs.point), bool)
        poses, positions, e0, e1, its = self._solve(
            obs, use, poses, fixed, point_ids, positions, index, True, first_iterations
        )
        if second_iterations > 0:
            use = self._chi2(obs, poses, positions, index)
            poses, positions, _, _, its2 = self._solve(
                obs, use, poses, fixed, point_ids, positions, index, False, second_iterations
            )
            its += its2
        inlier = self._chi2(obs, poses, positions, index)
        for k in involved:
            if int(k) not in fixed:
                slam_map.keyframes[int(k)].pose_wc = poses[int(k)]
        slam_map.points.position.view[point_ids] = positions
        erased = slam_map.erase_observations(obs.point[~inlier], obs.keyframe[~inlier])
        slam_map.update_geometry(point_ids)
        return Adjustment(
            free=np.array(sorted(set(int(k) for k in involved) - fixed), np.int64),
            fixed=np.array(sorted(fixed), np.int64),
            points=point_ids,
            observations=len(obs.point),
            outliers=erased,
            error=(e0, e1),
            iterations=its,
        )

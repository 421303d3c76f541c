"""Pose hypotheses from 2D–3D matches and their refinement: PnP-RANSAC (``cv2.solvePnPRansac``,
AP3P minimal sets, or EPnP seeded with a predicted pose) or PROSAC (OpenCV's USAC sampling the
matches in order of descriptor distance, ``SamplingSettings.sampler``), then the RGB-D refinement
alternated with re-classifying inliers by ORB-SLAM2's χ² test (5.991 / 7.815 × the level's
variance), and ORB-SLAM2's ``PoseOptimization`` for the motion model (:meth:`optimise_all`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..frontend.orb import Features
from ..geometry import from_rvec, to_rvec
from ..optim.pose import CHI2_MONO, CHI2_STEREO, chi2, observations, optimise_pose


@dataclass(frozen=True)
class SamplingSettings:
    """How pose hypotheses are drawn and refined: ``sampler`` ``ransac`` | ``prosac``,
    ``ransac_iterations``, ``ransac_threshold`` (px), ``refine_rounds`` of the refinement,
    ``rgbd_refinement`` (depth residuals too), ``pose_tolerance`` (the refinement's
    convergence step, metres and radians)."""

    sampler: str = "ransac"
    ransac_iterations: int = 100
    ransac_threshold: float = 3.0
    refine_rounds: int = 4
    rgbd_refinement: bool = True
    pose_tolerance: float = 1e-5


class PoseSampler:
    """Camera poses from matches ``world[i] <-> keypoint kp[i]`` of one frame.

    ``k`` (3, 3) camera matrix, ``sigma2`` (levels,) each pyramid level's variance, ``bf`` fx ×
    the virtual baseline (px · m); ``rng``: None = RANSAC draws its samples as OpenCV does for the
    given matches (deterministic), a generator perturbs the sampling reproducibly, for repeated
    runs (:meth:`sampling_order`).
    """

    def __init__(
        self,
        config: SamplingSettings,
        k: np.ndarray,
        sigma2: np.ndarray,
        bf: float,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.config = config
        self.k = k
        self.sigma2 = sigma2
        self.bf = bf
        self.rng = rng

    def pnp(
        self,
        world: np.ndarray,
        features: Features,
        kp: np.ndarray,
        guess_cw: np.ndarray | None,
        distance: np.ndarray,
    ) -> np.ndarray | None:
        """Pose ``T_cw`` (4, 4) of a frame tracked from a prior ``guess_cw`` (RANSAC seeds EPnP
        with it; None = AP3P) and Hamming ``distance`` (PROSAC's order), 6 inliers needed."""
        cfg = self.config
        if len(world) < 6:
            return None
        if cfg.sampler == "prosac":
            ok, rvec, tvec, inliers = self.prosac(world, features, kp, distance)
            found = self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inliers, 6)
            return None if found is None else found[0]
        ok, rvec, tvec, inliers = self.ransac(
            world, features.uv[kp], cfg.ransac_iterations, guess_cw
        )
        found = self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inliers, 6)
        return None if found is None else found[0]

    def pnp_global(
        self, world: np.ndarray, features: Features, kp: np.ndarray, distance: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Pose of a frame from matches ``world[i] <-> keypoint kp[i]`` (Hamming ``distance``)
        without a prior (relocalisation, loop verification): PnP-RANSAC (or PROSAC) and the
        RGB-D refinement, 10 inliers needed. Returns ``(pose_cw, inlier mask)`` or None."""
        if self.config.sampler == "prosac":
            iterations = max(self.config.ransac_iterations, 300)
            ok, rvec, tvec, inl = self.prosac(world, features, kp, distance, iterations)
            return self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inl, 10)
        ok, rvec, tvec, inliers = self.ransac(
            world, features.uv[kp], max(self.config.ransac_iterations, 300)
        )
        return self._refined_hypothesis(world, features, kp, ok, rvec, tvec, inliers, 10)

    def ransac(
        self,
        world: np.ndarray,
        uv: np.ndarray,
        iterations: int,
        guess_cw: np.ndarray | None = None,
    ):
        """OpenCV's PnP-RANSAC of ``world[i] <-> uv[i]``, the matches in
        :meth:`sampling_order`: AP3P minimal sets, or EPnP starting from the pose ``guess_cw``
        when given. Returns ``(ok, rvec, tvec, inliers)``."""
        if guess_cw is not None:
            rvec, tvec = to_rvec(guess_cw)
            use_guess = True
        else:
            rvec, tvec = np.zeros((3, 1)), np.zeros((3, 1))
            use_guess = False
        order = self.sampling_order(len(world))
        return cv2.solvePnPRansac(
            world[order].reshape(-1, 1, 3).astype(np.float64),
            uv[order].reshape(-1, 1, 2).astype(np.float64),
            self.k,
            None,
            rvec,
            tvec,
            useExtrinsicGuess=use_guess,
            iterationsCount=iterations,
            reprojectionError=self.config.ransac_threshold,
            confidence=0.999,
            flags=cv2.SOLVEPNP_EPNP if use_guess else cv2.SOLVEPNP_AP3P,
        )

    def prosac(
        self,
        world: np.ndarray,
        features: Features,
        kp: np.ndarray,
        distance: np.ndarray,
        iterations: int | None = None,
    ):
        """PnP with OpenCV's USAC and PROSAC sampling: matches sorted by descriptor distance
        (PROSAC draws its samples from the best-ranked matches first). USAC's local optimisation
        and final polishing are off: the RGB-D refinement that follows does that work (with
        them, ``flags=cv2.USAC_PROSAC``, a call costs about 4 ms of CPU instead of 0.8 ms for
        300 matches). Returns ``(ok, rvec, tvec, inliers)``, inlier indices in sorted order."""
        order = np.argsort(distance, kind="stable")
        params = cv2.UsacParams()
        params.sampler = cv2.SAMPLING_PROSAC
        params.loMethod = cv2.LOCAL_OPTIM_NULL
        params.final_polisher = cv2.NONE_POLISHER
        params.maxIterations = int(iterations or self.config.ransac_iterations)
        params.threshold = self.config.ransac_threshold
        params.confidence = 0.999
        if self.rng is not None:  # USAC seeds its own generator: give it a drawn state
            params.randomGeneratorState = int(self.rng.integers(1, 2**31))
        ok, _, rvec, tvec, inliers = cv2.solvePnPRansac(
            world[order].reshape(-1, 1, 3).astype(np.float64),
            features.uv[kp[order]].reshape(-1, 1, 2).astype(np.float64),
            self.k,
            None,
            params=params,
        )
        return ok, rvec, tvec, inliers

    def sampling_order(self, n: int) -> np.ndarray | slice:
        """The order in which ``n`` matches are handed to OpenCV's RANSAC: as given (no seed),
        or a seeded random permutation. OpenCV's RANSAC seeds its generator with a constant, so
        the samples it draws are fixed by the order of the matches; permuting them draws other
        minimal sets, a perturbation of the sampling alone (the inliers and the refined pose are
        computed on the matches in their given order)."""
        return slice(None) if self.rng is None else self.rng.permutation(n)

    def _refined_hypothesis(
        self, world, features, kp, ok, rvec, tvec, inliers, min_inliers: int
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The RANSAC pose refined (:meth:`refine_pose`) and its inlier mask over the given
        matches (in their given order), or None with too few inliers."""
        if not ok or inliers is None or len(inliers) < min_inliers:
            return None
        pose_cw, inl = self.refine_pose(world, features, kp, from_rvec(rvec, tvec))
        return (pose_cw, inl) if inl.sum() >= min_inliers else None

    def refine_pose(
        self, world: np.ndarray, features: Features, kp: np.ndarray, pose_cw: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Refine a pose on matches ``world[i] <-> keypoint kp[i]``; returns ``(pose_cw, inliers)``.

        ``refine_rounds`` rounds, each re-classifying inliers by the χ² test (ORB-SLAM2): with
        ``rgbd_refinement`` the RGB-D Gauss–Newton of :mod:`..optim.pose` (depth as a virtual stereo
        coordinate), else OpenCV's ``solvePnPRefineLM`` on the reprojection error alone.
        """
        cfg = self.config
        uv = features.uv[kp]
        inv_sigma2 = 1.0 / self.sigma2[features.octave[kp]]
        depth = features.depth[kp] if cfg.rgbd_refinement else np.zeros(len(kp), np.float32)
        obs, stereo = observations(uv, depth, self.bf)
        inl = self.inliers(world, obs, stereo, inv_sigma2, pose_cw)
        for _ in range(cfg.refine_rounds):
            if inl.sum() < 6:
                break
            if cfg.rgbd_refinement:
                pose_cw = optimise_pose(
                    self.k, self.bf, pose_cw, world[inl], obs[inl], stereo[inl], inv_sigma2[inl],
                    tolerance=cfg.pose_tolerance,
                )  # fmt: skip
            else:
                rvec, tvec = to_rvec(pose_cw)
                rvec, tvec = cv2.solvePnPRefineLM(
                    world[inl].reshape(-1, 1, 3),
                    uv[inl].reshape(-1, 1, 2),
                    self.k,
                    None,
                    rvec,
                    tvec,
                )
                pose_cw = from_rvec(rvec, tvec)
            new = self.inliers(world, obs, stereo, inv_sigma2, pose_cw)
            if np.array_equal(new, inl):
                break
            inl = new
        return pose_cw, inl

    def inliers(
        self,
        world: np.ndarray,
        obs: np.ndarray,
        stereo: np.ndarray,
        inv_sigma2: np.ndarray,
        pose_cw: np.ndarray,
    ) -> np.ndarray:
        e2, front = chi2(self.k, self.bf, pose_cw, world, obs, stereo, inv_sigma2)
        return front & (e2 < np.where(stereo, CHI2_STEREO, CHI2_MONO))

    def optimise_all(
        self, world: np.ndarray, features: Features, kp: np.ndarray, pose_cw: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """ORB-SLAM2's ``PoseOptimization``: every match starts as an inlier; four rounds, each
        optimising from ``pose_cw`` on the current inliers (Huber kernel in the first three)
        and re-classifying every match by the χ² test. Returns ``(pose_cw, inlier mask)``."""
        uv = features.uv[kp]
        inv_sigma2 = 1.0 / self.sigma2[features.octave[kp]]
        obs, stereo = observations(uv, features.depth[kp], self.bf)
        inl = np.ones(len(kp), bool)
        start, pose = pose_cw, pose_cw
        for round_ in range(4):
            if inl.sum() < 6:
                break
            pose = optimise_pose(
                self.k, self.bf, start, world[inl], obs[inl], stereo[inl], inv_sigma2[inl],
                robust=round_ < 3, tolerance=self.config.pose_tolerance,
            )  # fmt: skip
            inl = self.inliers(world, obs, stereo, inv_sigma2, pose)
        return pose, inl

"""ORB front end as ORB-SLAM2's TUM settings: spread keypoints, descriptors, depth back-projection.

Per pyramid level (scale 1.2, 8 levels) FAST corners are detected with threshold 20; grid cells
(30 px at that level) where none is found are searched again with threshold 7. Each level keeps
its share of the 1000 features (ORB-SLAM2's geometric split) chosen by grid bucketing: the best
corner of every cell first, then the second best, ... so keypoints spread over the whole image
instead of piling up on the most textured object. Orientation is the intensity centroid over a
radius-15 disc (as ORB); descriptors are OpenCV's rBRIEF on the blurred pyramid.

Keypoints with a depth measurement inside ``[min_depth, max_depth]`` are back-projected to 3D
camera coordinates; the others are still matched as 2D observations. ``max_depth`` plays the
role of ORB-SLAM2's "close point" threshold (``ThDepth`` 40 × the Kinect's 7.5 cm virtual
baseline = 3 m): Kinect depth noise grows with the square of the distance. The default is 4 m
because in the synthetic room (6 × 5 m) half of the visible depth lies beyond 3 m, and cutting it
leaves too few map points at the far end of the room; set ``max_depth: 3.0`` for ORB-SLAM2's value.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, fields, replace
from operator import attrgetter

import cv2
import numpy as np

from uss_slam.core.ranges import MAX_FEATURES
from uss_slam.core.schema import SchemaError, check_fields, ranged
from uss_slam.core.tum_io import CameraIntrinsics

HALF_PATCH = 15
"""Radius of ORB's orientation disc (patch size 31), pixels at the keypoint's level."""
EDGE = 19
"""Keypoints keep this far from each level's border (ORB-SLAM2's EDGE_THRESHOLD)."""


MAX_LEVELS = 32
"""The most pyramid levels (ORB-SLAM's 8 at scale 1.2 span 3.6x; 32 span 300x, past any
frame's size)."""


@dataclass(frozen=True)
class OrbConfig:
    """ORB extraction settings (defaults: ORB-SLAM2's TUM RGB-D configuration)."""

    n_features: int = ranged(1000, min=1, max=MAX_FEATURES)
    scale_factor: float = ranged(1.2, gt=1.0)
    n_levels: int = ranged(8, min=1, max=MAX_LEVELS)
    ini_fast: int = ranged(20, min=1, max=255)
    """FAST threshold, grey levels (0-255)."""
    min_fast: int = ranged(7, min=1, max=255)
    """FAST threshold of the second search, grey levels; at most ``ini_fast``."""
    cell_size: int = ranged(30, min=8)
    """Side of the cells searched again with ``min_fast`` when ``ini_fast`` finds nothing, px."""
    min_depth: float = ranged(0.1, min=0)
    max_depth: float = ranged(4.0, gt=0)
    """Depth beyond this is not back-projected, metres (see the module docstring)."""

    def __post_init__(self) -> None:
        check_fields(self)  # the ranges above; then the rules across fields
        if self.min_fast > self.ini_fast:
            raise SchemaError("min_fast", f"an integer <= {{ini_fast}} ({self.ini_fast})",
                              self.min_fast)  # fmt: skip
        if self.min_depth >= self.max_depth:
            raise SchemaError("min_depth", f"a number < {{max_depth}} ({self.max_depth})",
                              self.min_depth)  # fmt: skip


@dataclass
class Features:
    """The ``N`` keypoints of one frame; every array has ``N`` rows.

    ``xy`` (N, 2) float32 pixel position in the (distorted) image; ``uv`` (N, 2) float64 the same
    point undistorted (equal to ``xy`` for a camera without distortion); ``octave`` (N,) int32
    pyramid level; ``angle`` (N,) float32 degrees; ``response`` (N,) float32 FAST score;
    ``descriptors`` (N, 32) uint8; ``depth`` (N,) float32 metres (0 = no usable depth);
    ``points`` (N, 3) float64 camera-frame coordinates, metres (NaN where ``depth`` is 0).
    """

    xy: np.ndarray
    uv: np.ndarray
    octave: np.ndarray
    angle: np.ndarray
    response: np.ndarray
    descriptors: np.ndarray
    depth: np.ndarray
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)

    @property
    def has_depth(self) -> np.ndarray:
        """``(N,)`` bool: the keypoint has a back-projected 3D point."""
        return self.depth > 0

    def subset(self, index: np.ndarray) -> Features:
        """The keypoints selected by a boolean mask or index array."""
        return Features(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    @classmethod
    def empty(cls) -> Features:
        return cls(
            xy=np.zeros((0, 2), np.float32),
            uv=np.zeros((0, 2)),
            octave=np.zeros(0, np.int32),
            angle=np.zeros(0, np.float32),
            response=np.zeros(0, np.float32),
            descriptors=np.zeros((0, 32), np.uint8),
            depth=np.zeros(0, np.float32),
            points=np.zeros((0, 3)),
        )


class OrbExtractor:
    """Extracts :class:`Features` from a grey image and its depth map."""

    def __init__(self, config: OrbConfig, camera: CameraIntrinsics) -> None:
        self.config = config
        self.camera = camera
        n, s = config.n_levels, config.scale_factor
        self.scales = s ** np.arange(n)
        """``(L,)`` scale of each level relative to level 0."""
        self.sigma2 = self.scales**2
        """``(L,)`` keypoint position variance per level, px² (ORB-SLAM2's convention)."""
        # ORB-SLAM2's split: level l gets a share proportional to (1/s)^l.
        share = config.n_features * (1 - 1 / s) / (1 - (1 / s) ** n)
        budgets, left = [], config.n_features
        for level in range(n - 1):
            take = int(round(share * (1 / s) ** level))
            budgets.append(take)
            left -= take
        budgets.append(max(left, 0))
        self.budgets = budgets
        self._fast_hi = cv2.FastFeatureDetector_create(config.ini_fast, True)
        self._fast_lo = cv2.FastFeatureDetector_create(config.min_fast, True)
        self._orb = cv2.ORB_create(
            nfeatures=config.n_features,
            scaleFactor=config.scale_factor,
            nlevels=config.n_levels,
            edgeThreshold=EDGE,
            patchSize=2 * HALF_PATCH + 1,
            fastThreshold=config.ini_fast,
        )
        # Disc of radius HALF_PATCH (ORB's umax rule) as (dx, dy) weights over the square
        # window around a keypoint, 0 outside the disc: (side², 2) float32.
        dy, dx = np.mgrid[-HALF_PATCH : HALF_PATCH + 1, -HALF_PATCH : HALF_PATCH + 1]
        inside = dx**2 + dy**2 <= HALF_PATCH**2 + HALF_PATCH  # ~ umax's rounding
        self._disc_weights = np.stack([(dx * inside).ravel(), (dy * inside).ravel()], axis=1)
        self._disc_weights = self._disc_weights.astype(np.float32)
        self._k = camera.matrix
        self._dist = np.asarray(camera.distortion, dtype=np.float64)

    # ------------------------------------------------------------------ detection

    def pyramid(self, gray: np.ndarray) -> list[np.ndarray]:
        """Level images (level 0 = ``gray``), each ``1/scale_factor`` the size of the previous."""
        levels = [gray]
        h, w = gray.shape
        for level in range(1, self.config.n_levels):
            size = (  # at least a pixel: levels past the frame's size find nothing
                max(1, int(round(w / self.scales[level]))),
                max(1, int(round(h / self.scales[level]))),
            )
            levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR))
        return levels

    def _detect_level(self, image: np.ndarray, budget: int) -> tuple[np.ndarray, np.ndarray]:
        """``(M, 2)`` float32 corner positions and ``(M,)`` scores chosen on one level."""
        h, w = image.shape
        lo_x, lo_y, hi_x, hi_y = EDGE, EDGE, w - EDGE, h - EDGE
        if budget <= 0 or hi_x - lo_x < 8 or hi_y - lo_y < 8:
            return np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        # FAST needs a 3 px ring around each tested pixel: detect on the region grown by 3 px.
        # OpenCV's FAST tests only the pixels at least 3 px inside the image it is given, so
        # every corner it finds there lies in the region (here and in the boxes below).
        roi = image[lo_y - 3 : hi_y + 3, lo_x - 3 : hi_x + 3]
        xy, score = _fast(self._fast_hi, roi, lo_x - 3, lo_y - 3)
        cell = self.config.cell_size
        nx = max(1, int(math.ceil((hi_x - lo_x) / cell)))
        ny = max(1, int(math.ceil((hi_y - lo_y) / cell)))
        occupied = np.zeros(nx * ny, dtype=bool)
        if len(xy):
            cx = np.minimum(((xy[:, 0] - lo_x) / cell).astype(np.int64), nx - 1)
            cy = np.minimum(((xy[:, 1] - lo_y) / cell).astype(np.int64), ny - 1)
            occupied[cy * nx + cx] = True
        # Search again with the low threshold, one call per horizontal run of empty cells: the
        # scan stays inside the empty (low-texture) area, where FAST rejects pixels fastest. The
        # corners of all runs are converted to arrays at once (per-run numpy calls would hold the
        # GIL about as long as FAST itself takes, beside the main thread's tracking).
        grid = np.zeros((ny, nx + 2), np.int8)
        grid[:, 1:-1] = ~occupied.reshape(ny, nx)
        edges = np.diff(grid, axis=1)
        run_rows, run_starts = np.nonzero(edges == 1)
        _, run_ends = np.nonzero(edges == -1)
        # Each run's box (x0, y0, x1, y1), its corners detected on the box grown by 3 px.
        all_boxes = np.empty((len(run_rows), 4), np.int64)
        all_boxes[:, 0] = lo_x + run_starts * cell
        all_boxes[:, 1] = lo_y + run_rows * cell
        all_boxes[:, 2] = np.minimum(lo_x + run_ends * cell, hi_x)
        all_boxes[:, 3] = np.minimum(all_boxes[:, 1] + cell, hi_y)
        detect = self._fast_lo.detect
        found = [
            detect(image[y0 - 3 : y1 + 3, x0 - 3 : x1 + 3]) for x0, y0, x1, y1 in all_boxes.tolist()
        ]
        counts = [len(corners) for corners in found]
        if any(counts):
            origin = np.repeat(all_boxes[:, :2].astype(np.float32) - np.float32(3), counts, axis=0)
            flat = list(itertools.chain.from_iterable(found))
            xy = np.concatenate([xy, cv2.KeyPoint_convert(flat).reshape(-1, 2) + origin])
            score = np.concatenate([score, _responses(flat)])
        if len(xy) <= budget:
            return xy, score
        # Grid bucketing: cells sized so that there are about `budget` of them; take rank-0
        # corners of all cells (best first), then rank-1 corners, ... until the budget is met.
        side = math.sqrt((hi_x - lo_x) * (hi_y - lo_y) / budget)
        bx = max(1, int(math.ceil((hi_x - lo_x) / side)))
        col = np.minimum(((xy[:, 0] - lo_x) / side).astype(np.int64), bx - 1)
        bucket = ((xy[:, 1] - lo_y) / side).astype(np.int64) * bx + col
        # FAST scores are integers in [0, 255], so (key, best score first) packs into one int64,
        # and a stable sort of it gives the two-key lexsort's order, ties by position. NumPy's
        # stable sort (timsort) is faster here than its default SIMD quicksort made stable by
        # distinct keys: FAST returns corners row by row, so the keys come in long sorted runs.
        worse = 255 - score.astype(np.int64)
        order = np.argsort(bucket * 256 + worse, kind="stable")
        sorted_bucket = bucket[order]
        first = np.concatenate(([0], np.flatnonzero(np.diff(sorted_bucket)) + 1))
        rank = np.arange(len(order)) - np.repeat(first, np.diff(first, append=len(order)))
        pick = order[np.argsort(rank * 256 + worse[order], kind="stable")[:budget]]
        return xy[pick], score[pick]

    def _orientation(self, image: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """``(M,)`` ORB intensity-centroid angle in degrees [0, 360) at level coordinates ``xy``."""
        if len(xy) == 0:
            return np.zeros(0, np.float32)
        # The (2r+1)² window at each keypoint, weighted by dx / dy inside the disc (0 outside):
        # the moments are integers below 2^24, so float32 sums are exact in any order.
        corner = np.rint(xy).astype(np.intp) - HALF_PATCH
        side = 2 * HALF_PATCH + 1
        windows = np.lib.stride_tricks.sliding_window_view(image, (side, side))
        patches = windows[corner[:, 1], corner[:, 0]].reshape(len(xy), -1).astype(np.float32)
        m10, m01 = (patches @ self._disc_weights).T
        return (np.degrees(np.arctan2(m01, m10)) % 360.0).astype(np.float32)

    # ------------------------------------------------------------------ public

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Spread, oriented keypoints of a grey image.

        Returns ``xy`` (N, 2) float32 level-0 pixel positions, ``octave`` (N,) int32, ``angle``
        (N,) float32 degrees and ``response`` (N,) float32 FAST scores, grouped by level.
        """
        xys, octaves, angles, responses = [], [], [], []
        for level, image in enumerate(self.pyramid(gray)):
            xy, score = self._detect_level(image, self.budgets[level])
            angles.append(self._orientation(image, xy))
            xys.append(xy * np.float32(self.scales[level]))
            octaves.append(np.full(len(xy), level, np.int32))
            responses.append(score)
        return (
            np.concatenate(xys).reshape(-1, 2),
            np.concatenate(octaves),
            np.concatenate(angles),
            np.concatenate(responses),
        )

    def __call__(self, gray: np.ndarray, depth: np.ndarray | None) -> Features:
        """Keypoints, descriptors and depth of one frame.

        ``gray`` (H, W) uint8; ``depth`` (H, W) float32 metres (0 = none) or None.
        """
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise ValueError(f"expected a (H, W) uint8 grey image, got {gray.dtype} {gray.shape}")
        xy, octave, angle, response = self.detect(gray)
        if len(xy) == 0:
            return Features.empty()
        sizes = (2 * HALF_PATCH + 1) * self.scales[octave]
        keypoints = list(  # class_id k: the keypoint's row
            map(
                cv2.KeyPoint,
                xy[:, 0].tolist(),
                xy[:, 1].tolist(),
                sizes.tolist(),
                angle.tolist(),
                response.tolist(),
                octave.tolist(),
                range(len(xy)),
            )
        )
        described, descriptors = self._orb.compute(gray, keypoints)
        if descriptors is None or not described:
            return Features.empty()
        # OpenCV may reorder (by level) or drop keypoints; class_id says which is which.
        kept = np.fromiter(map(_CLASS_ID, described), np.int64, len(described))
        if len(kept) != len(xy) or np.any(kept[1:] < kept[:-1]):
            order = np.argsort(kept, kind="stable")
            kept, descriptors = kept[order], descriptors[order]
        xy, octave, angle, response = xy[kept], octave[kept], angle[kept], response[kept]
        return self.describe(xy, octave, angle, response, descriptors, depth)

    def describe(
        self,
        xy: np.ndarray,
        octave: np.ndarray,
        angle: np.ndarray,
        response: np.ndarray,
        descriptors: np.ndarray,
        depth: np.ndarray | None,
    ) -> Features:
        """Assemble :class:`Features`: undistort positions, sample depth, back-project."""
        uv = self.undistort(xy)
        z = self.sample_depth(xy, depth)
        points = self.backproject(uv, z)
        return Features(xy, uv, octave, angle, response, descriptors, z, points)

    def with_depth(self, features: Features, depth: np.ndarray) -> Features:
        """``features`` extracted without a depth map (``self(gray, None)``), given the frame's
        ``(H, W)`` float32 ``depth`` (metres): the same :class:`Features` as ``self(gray,
        depth)``. The frame reader process extracts without depth; the depth is read and
        sampled in the main process."""
        z = self.sample_depth(features.xy, depth)
        return replace(features, depth=z, points=self.backproject(features.uv, z))

    def sample_depth(self, xy: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """``(N,)`` float32 depth at the pixels nearest ``xy`` (N, 2), metres; 0 outside
        ``[min_depth, max_depth]`` and everywhere when ``depth`` is None."""
        n = len(xy)
        z = np.zeros(n, np.float32)
        if depth is not None and n:
            h, w = depth.shape
            col = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
            row = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
            z = depth[row, col].astype(np.float32)
            z[(z < self.config.min_depth) | (z > self.config.max_depth)] = 0.0
        return z

    def undistort(self, xy: np.ndarray) -> np.ndarray:
        """``(N, 2)`` undistorted pixel coordinates of image positions ``xy`` (float64)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if not self.camera.has_distortion or len(xy) == 0:
            return xy.copy()
        return cv2.undistortPoints(xy.reshape(-1, 1, 2), self._k, self._dist, P=self._k).reshape(
            -1, 2
        )

    def backproject(self, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``(N, 3)`` camera-frame points of undistorted pixels ``uv`` at depths ``z`` (0 -> NaN)."""
        cam = self.camera
        z = np.asarray(z, dtype=np.float64)
        pts = np.empty((len(z), 3))
        pts[:, 0] = (uv[:, 0] - cam.cx) * z / cam.fx
        pts[:, 1] = (uv[:, 1] - cam.cy) * z / cam.fy
        pts[:, 2] = z
        pts[z <= 0] = np.nan
        return pts


def _fast(
    detector: cv2.FastFeatureDetector, image: np.ndarray, ox: int, oy: int
) -> tuple[np.ndarray, np.ndarray]:
    found = detector.detect(image)
    if not found:
        return np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
    xy = cv2.KeyPoint_convert(found).reshape(-1, 2) + np.float32([ox, oy])
    return xy, _responses(found)


_RESPONSE, _CLASS_ID = attrgetter("response"), attrgetter("class_id")


def _responses(keypoints: list[cv2.KeyPoint] | tuple[cv2.KeyPoint, ...]) -> np.ndarray:
    """``(N,)`` float32 FAST scores of OpenCV keypoints (no Python frame per keypoint)."""
    return np.fromiter(map(_RESPONSE, keypoints), np.float32, len(keypoints))

"""Poses, depth and labels of synthetic sequences agree with each other; styles never move them."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.tum_io import (
    DEPTH_SCALE,
    CameraIntrinsics,
    matrix_to_quat,
    quat_to_matrix,
    read_file_list,
    read_trajectory,
)
from uss_slam.synthetic.styles import DEPTH_NOISE_K

PERSON = CLASS_NAMES.index("person")


def _pose_at(path: Path, stamp: float) -> np.ndarray:
    """Ground truth at ``stamp``: linear position, normalised-lerp rotation (100 Hz is dense)."""
    gt = read_trajectory(path)
    k = int(np.searchsorted(gt.stamps, stamp)) - 1
    f = (stamp - gt.stamps[k]) / (gt.stamps[k + 1] - gt.stamps[k])
    assert 0 <= f <= 1
    q0, q1 = gt.quaternions[k], gt.quaternions[k + 1]
    q1 = q1 if np.dot(q0, q1) >= 0 else -q1
    q = (1 - f) * q0 + f * q1
    pose = np.eye(4)
    pose[:3, :3] = quat_to_matrix(q / np.linalg.norm(q))
    pose[:3, 3] = (1 - f) * gt.positions[k] + f * gt.positions[k + 1]
    return pose


def _read(root: Path, i: int) -> tuple[float, np.ndarray, np.ndarray]:
    rgb = read_file_list(root / "rgb.txt")
    depth = read_file_list(root / "depth.txt")
    d = cv2.imread(str(depth.resolve(i)), cv2.IMREAD_UNCHANGED).astype(np.float64) / DEPTH_SCALE
    labels = cv2.imread(str(root / "labels" / Path(rgb.files[i]).name), cv2.IMREAD_UNCHANGED)
    return float(rgb.stamps[i]), d, labels


def test_static_points_reproject_onto_the_same_surface(synthetic_sequence) -> None:
    root = synthetic_sequence(preset="walking_xyz", frames=30, size=(320, 240), style="source")
    cam = CameraIntrinsics.from_yaml(root / "intrinsics.yaml")
    k = cam.matrix
    for i, j in ((2, 27), (27, 14)):
        stamp_i, depth_i, labels_i = _read(root, i)
        stamp_j, depth_j, labels_j = _read(root, j)
        # camera i -> camera j from the ground truth alone
        rel = np.linalg.inv(_pose_at(root / "groundtruth.txt", stamp_j)) @ _pose_at(
            root / "groundtruth.txt", stamp_i
        )
        v, u = np.mgrid[0 : cam.height, 0 : cam.width]
        ok = (depth_i > 0) & (labels_i != PERSON)
        z = depth_i[ok]
        pts = np.stack([(u[ok] - k[0, 2]) / k[0, 0] * z, (v[ok] - k[1, 2]) / k[1, 1] * z, z], 1)
        q = pts @ rel[:3, :3].T + rel[:3, 3]
        pu = k[0, 0] * q[:, 0] / q[:, 2] + k[0, 2]
        pv = k[1, 1] * q[:, 1] / q[:, 2] + k[1, 2]
        inside = (
            (q[:, 2] > 0) & (pu >= 0) & (pu < cam.width - 1) & (pv >= 0) & (pv < cam.height - 1)
        )
        pu, pv, zq = pu[inside], pv[inside], q[inside, 2]
        # inverse depth is linear across a plane in the image: interpolate it bilinearly
        inv = np.where(depth_j > 0, 1 / np.maximum(depth_j, 1e-9), 0.0)
        x0, y0 = np.floor(pu).astype(int), np.floor(pv).astype(int)
        fx, fy = pu - x0, pv - y0
        inv_j = (inv[y0, x0] * (1 - fx) + inv[y0, x0 + 1] * fx) * (1 - fy) + (
            inv[y0 + 1, x0] * (1 - fx) + inv[y0 + 1, x0 + 1] * fx
        ) * fy
        # compare away from depth edges and grazing surfaces, where the four neighbours agree
        corners = np.stack([depth_j[y0, x0], depth_j[y0, x0 + 1], depth_j[y0 + 1, x0],
                            depth_j[y0 + 1, x0 + 1]])  # fmt: skip
        smooth = (corners.min(0) > 0) & (np.ptp(corners, axis=0) < 0.005 * corners.min(0))
        visible = labels_j[np.rint(pv).astype(int), np.rint(pu).astype(int)] != PERSON
        test = smooth & visible
        assert test.sum() > 0.25 * cam.width * cam.height
        err = zq[test] - 1 / inv_j[test]
        # a static point never lies in front of the surface camera j sees there; it may lie
        # behind it (hidden by a nearer static object), rarely; all others agree within 1 cm
        assert np.all(err > -0.01), np.sort(err)[:5]
        assert np.mean(err > 0.01) < 0.02
        assert np.median(np.abs(err)) < 0.001


def test_style_changes_appearance_only(synthetic_sequence) -> None:
    src = synthetic_sequence(preset="walking_xyz", frames=30, size=(320, 240), style="source")
    tgt = synthetic_sequence(preset="walking_xyz", frames=30, size=(320, 240), style="target")
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        assert (src / name).read_bytes() == (tgt / name).read_bytes(), name
    # the same camera; only the target style declares the depth noise it adds
    cams = [CameraIntrinsics.from_yaml(d / "intrinsics.yaml") for d in (src, tgt)]
    assert cams[0].depth_noise is None and cams[1].depth_noise == DEPTH_NOISE_K
    assert replace(cams[1], depth_noise=None) == cams[0]
    for label in sorted((src / "labels").iterdir()):
        assert label.read_bytes() == (tgt / "labels" / label.name).read_bytes()
    for i in (0, 15, 29):
        _, d_src, _ = _read(src, i)
        _, d_tgt, _ = _read(tgt, i)
        both = (d_src > 0) & (d_tgt > 0)
        # Kinect-like noise: sigma 1.2 mm + 1.9 mm * (z - 0.4)^2, so well within 5 sigma + 1 mm
        sigma = 0.0012 + 0.0019 * (d_src[both] - 0.4) ** 2
        assert np.all(np.abs(d_tgt[both] - d_src[both]) < 5 * sigma + 0.001)
        # and holes: the target has more missing depth, concentrated at depth edges
        assert (d_tgt == 0).mean() > (d_src == 0).mean() + 0.01
        edges = cv2.dilate(d_src.astype(np.float32), np.ones((3, 3))) - cv2.erode(
            d_src.astype(np.float32), np.ones((3, 3))
        ) > 0.1 * np.maximum(d_src, 0.1)
        holes = (d_tgt == 0) & (d_src > 0.45)
        assert holes[edges].mean() > 5 * holes[~edges].mean()
        rgb_src = cv2.imread(str(read_file_list(src / "rgb.txt").resolve(i)))
        rgb_tgt = cv2.imread(str(read_file_list(tgt / "rgb.txt").resolve(i)))
        assert np.abs(rgb_src.astype(int) - rgb_tgt.astype(int)).mean() > 10


def test_ground_truth_matches_the_rendered_poses(synthetic_sequence) -> None:
    """The 100 Hz ground truth interpolated at an image stamp is the pose that image was
    rendered from (to well below a millimetre and a hundredth of a degree)."""
    from uss_slam.synthetic import SequenceRenderer

    root = synthetic_sequence(preset="walking_halfsphere", frames=12, size=(64, 48))
    seq = SequenceRenderer("walking_halfsphere", 12, (64, 48), seed=0, style="target")
    rgb = read_file_list(root / "rgb.txt")
    np.testing.assert_array_equal(rgb.stamps, seq.stamps)
    for i in range(12):
        expected = seq.pose(seq.stamps[i])
        got = _pose_at(root / "groundtruth.txt", rgb.stamps[i])
        assert np.linalg.norm(got[:3, 3] - expected[:3, 3]) < 2e-4
        dq = matrix_to_quat(got[:3, :3].T @ expected[:3, :3])
        assert np.degrees(2 * np.arccos(min(1.0, abs(dq[3])))) < 0.01

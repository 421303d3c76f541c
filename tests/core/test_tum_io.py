"""TUM text formats: round trips, rotations, association, and errors that name file and line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uss_slam.core.errors import DataFormatError
from uss_slam.core.tum_io import (
    TUM_CAMERAS,
    CameraIntrinsics,
    Trajectory,
    associate,
    matrix_to_quat,
    quat_to_matrix,
    read_file_list,
    read_trajectory,
    write_file_list,
    write_trajectory,
)


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))


def test_rotation_round_trip_and_orthonormality() -> None:
    rng = np.random.default_rng(0)
    r = random_rotations(200, rng)
    assert np.allclose(r @ np.swapaxes(r, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)
    q = matrix_to_quat(r)
    assert np.all(q[:, 3] >= 0)
    assert np.allclose(quat_to_matrix(q), r, atol=1e-12)
    # 180-degree rotations (trace -1) take the non-scalar pivots.
    flips = np.array([np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])])
    assert np.allclose(quat_to_matrix(matrix_to_quat(flips)), flips, atol=1e-12)


def test_quaternion_convention_is_hamilton_xyzw() -> None:
    # 90 degrees about z: x axis goes to y.
    q = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    assert np.allclose(quat_to_matrix(q) @ [1.0, 0, 0], [0, 1.0, 0])


def test_trajectory_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    poses = np.tile(np.eye(4), (50, 1, 1))
    poses[:, :3, :3] = random_rotations(50, rng)
    poses[:, :3, 3] = rng.normal(size=(50, 3))
    stamps = 1305031102.175304 + np.arange(50) / 30.0
    write_trajectory(tmp_path / "t.txt", Trajectory.from_matrices(stamps, poses), comment="test")
    back = read_trajectory(tmp_path / "t.txt")
    assert np.allclose(back.stamps, stamps, atol=1e-6)
    assert np.allclose(back.matrices(), poses, atol=1e-6)


def test_file_list_round_trip_with_comments(tmp_path: Path) -> None:
    stamps = [1.0, 1.033333, 1.066667]
    write_file_list(
        tmp_path / "rgb.txt", stamps, ["rgb/1.000000.png", "rgb/1.033333.png", "rgb/1.066667.png"]
    )
    lst = read_file_list(tmp_path / "rgb.txt")
    assert (tmp_path / "rgb.txt").read_text().startswith("# color images\n")
    assert np.allclose(lst.stamps, stamps)
    assert lst.resolve(1) == tmp_path / "rgb/1.033333.png"


@pytest.mark.parametrize(
    ("content", "line", "fragment"),
    [
        ("# c\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n", 3, "expected 8 columns"),
        ("1.0 0 0 0 0 0 0 1\n2.0 0 x 0 0 0 0 1\n", 2, "expected a number for ty"),
        ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 2\n", 2, "unit norm"),
        ("1.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n", 2, "timestamps must increase"),
        ("1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", 2, "duplicate timestamp"),
        ("1.0 0 0 0 0 0 0 1\n2.0 0 nan 0 0 0 0 1\n", 2, "finite"),
    ],
)
def test_bad_trajectory_names_file_and_line(
    tmp_path: Path, content: str, line: int, fragment: str
) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(DataFormatError) as info:
        read_trajectory(path)
    assert info.value.line == line
    assert str(info.value).startswith(f"{path}:{line}: ")
    assert fragment in str(info.value)


def test_bad_file_list_and_missing_file(tmp_path: Path) -> None:
    (tmp_path / "rgb.txt").write_text("# x\n1.0 rgb/a.png extra\n")
    with pytest.raises(DataFormatError, match=r"rgb.txt:2: expected 'timestamp filename'"):
        read_file_list(tmp_path / "rgb.txt")
    with pytest.raises(DataFormatError, match="file not found"):
        read_file_list(tmp_path / "missing.txt")


def test_associate_greedy_unique_with_offset() -> None:
    rgb = np.array([0.0, 0.033, 0.066, 0.1, 0.5])
    depth = np.array([0.004, 0.036, 0.061, 0.104])
    i, j = associate(rgb, depth)
    assert i.tolist() == [0, 1, 2, 3] and j.tolist() == [0, 1, 2, 3]
    # With an offset that shifts depth by one frame, pairs move by one.
    i, j = associate(rgb, depth, offset=0.03)
    assert i.tolist() == [1, 2, 3] and j.tolist() == [0, 1, 2]
    # Two candidates for one stamp: the closer pair wins and the other stamp finds no partner.
    i, j = associate(np.array([1.0, 1.015]), np.array([1.012]))
    assert i.tolist() == [1] and j.tolist() == [0]


def test_intrinsics_yaml_round_trip_and_errors(tmp_path: Path) -> None:
    cam = TUM_CAMERAS["fr3"].scaled(320, 240)
    assert cam.fx == pytest.approx(267.7) and cam.cx == pytest.approx(159.8)
    cam.to_yaml(tmp_path / "intrinsics.yaml")
    assert CameraIntrinsics.from_yaml(tmp_path / "intrinsics.yaml") == cam
    (tmp_path / "bad.yaml").write_text("fx: 1\n")
    with pytest.raises(DataFormatError, match="bad.yaml: expected a mapping with keys"):
        CameraIntrinsics.from_yaml(tmp_path / "bad.yaml")
    assert TUM_CAMERAS["fr1"].has_distortion and not TUM_CAMERAS["fr3"].has_distortion

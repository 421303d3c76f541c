"""TUM text formats: round trips, rotations, association, and errors that name file and line."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

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
    read_tum_folder,
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


def test_rotations_match_the_closed_form_and_tum_sign() -> None:
    """Against the textbook formula for ``qx qy qz qw`` (Hamilton) and ``qw >= 0``."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    expected = np.stack(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    ).transpose(2, 0, 1)
    np.testing.assert_allclose(quat_to_matrix(q), expected, atol=1e-15)
    back = matrix_to_quat(expected)
    np.testing.assert_allclose(back, np.where(q[:, 3:] < 0, -q, q), atol=1e-14)
    assert quat_to_matrix(q.reshape(50, 10, 4)).shape == (50, 10, 3, 3)
    assert matrix_to_quat(expected.reshape(5, 100, 3, 3)).shape == (5, 100, 4)
    assert quat_to_matrix(np.zeros((0, 4))).shape == (0, 3, 3)
    assert matrix_to_quat(np.zeros((0, 3, 3))).shape == (0, 4)
    # Non-unit input is normalised, as TUM files hold 4 decimals.
    np.testing.assert_allclose(quat_to_matrix(2.0 * q[:3]), expected[:3], atol=1e-15)
    np.testing.assert_allclose(Rotation.from_matrix(expected).as_quat(canonical=True), back,
                               atol=1e-14)  # fmt: skip


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
    with pytest.raises(DataFormatError, match="does not exist"):
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


def test_a_sequences_intrinsics_yaml_that_is_a_folder_or_names_a_key_twice_is_refused(
    tmp_path: Path,
) -> None:
    """Not taken as missing (the fr3 fallback) nor read with the last of a repeated key."""
    from uss_slam.core.tum_camera import resolve_camera

    (tmp_path / "intrinsics.yaml").mkdir()
    with pytest.raises(DataFormatError, match=r"intrinsics.yaml: is a folder"):
        resolve_camera(None, tmp_path, (640, 480))
    (tmp_path / "intrinsics.yaml").rmdir()
    TUM_CAMERAS["fr3"].to_yaml(tmp_path / "intrinsics.yaml")
    text = (tmp_path / "intrinsics.yaml").read_text()
    (tmp_path / "intrinsics.yaml").write_text(text + "fx: 525.0\n")
    with pytest.raises(DataFormatError, match=r"the key 'fx' is given twice \(first at line 1\)"):
        resolve_camera(None, tmp_path, (640, 480))


def test_intrinsics_declare_an_optional_depth_noise(tmp_path: Path) -> None:
    # a sensor whose depth noise is known (a synthetic one) declares it; a real Kinect does not
    assert all(cam.depth_noise is None for cam in TUM_CAMERAS.values())
    TUM_CAMERAS["fr3"].to_yaml(tmp_path / "a.yaml")
    assert "depth_noise" not in (tmp_path / "a.yaml").read_text()
    noisy = replace(TUM_CAMERAS["fr3"], depth_noise=0.0019)
    noisy.to_yaml(tmp_path / "b.yaml")
    back = CameraIntrinsics.from_yaml(tmp_path / "b.yaml")
    assert back == noisy and back.depth_noise == 0.0019
    assert back.scaled(320, 240).depth_noise == 0.0019


GOOD_INTRINSICS = {"fx": 500.0, "fy": 500.0, "cx": 15.5, "cy": 11.5, "width": 32, "height": 24}


@pytest.mark.parametrize(
    ("key", "value", "fragment"),
    [
        ("fx", 0, "fx must be > 0, got 0"),
        ("fy", -2.5, "fy must be > 0, got -2.5"),
        ("fx", ".nan", "fx must be a finite number, got nan"),
        ("fy", ".inf", "fy must be a finite number, got inf"),
        ("fx", "'abc'", "fx must be a number, got 'abc'"),
        ("depth_scale", 0, "depth_scale must be > 0, got 0"),
        ("depth_scale", ".nan", "depth_scale must be a finite number"),
        ("depth_noise", -0.001, "depth_noise must be >= 0, got -0.001"),
        ("depth_noise", "'low'", "depth_noise must be a number, got 'low'"),
        ("cx", 32, "cx must lie inside the image (0 <= cx < width 32), got 32"),
        ("cx", -1, "cx must lie inside the image"),
        ("cy", 30.5, "cy must lie inside the image (0 <= cy < height 24), got 30.5"),
        ("width", 32.5, "width must be a whole number of pixels, got 32.5"),
        ("height", 0, "height must be > 0"),
        ("distortion", "[0, 0, 0]", "distortion needs a list of 4, 5 or 8 coefficients, got 3"),
        ("distortion", "[0, .nan, 0, 0, 0]", "distortion[1] must be a finite number"),
        ("focal", 1, "unknown key 'focal'; expected fx, fy, cx, cy, width, height, distortion"),
    ],
)
def test_intrinsics_values_are_checked_one_line_naming_file_and_key(
    tmp_path: Path, key: str, value: object, fragment: str
) -> None:
    path = tmp_path / "intrinsics.yaml"
    entries = {**GOOD_INTRINSICS, key: value}
    path.write_text("".join(f"{k}: {v}\n" for k, v in entries.items()))
    with pytest.raises(DataFormatError) as info:
        CameraIntrinsics.from_yaml(path)
    message = str(info.value)
    assert message == f"{path}: {fragment}" or message.startswith(f"{path}: {fragment}")
    assert len(message.splitlines()) == 1


def _folder(root: Path, n: int = 4, depth_offset: float = 0.004) -> Path:
    stamps = 10.0 + np.arange(n) / 30.0
    for sub in ("rgb", "depth", "labels"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    names = [f"rgb/{s:.6f}.png" for s in stamps]
    depths = [f"depth/{s + depth_offset:.6f}.png" for s in stamps]
    for name in names + depths + [f"labels/{s:.6f}.png" for s in stamps]:
        (root / name).write_bytes(b"")
    write_file_list(root / "rgb.txt", stamps, names)
    write_file_list(root / "depth.txt", stamps + depth_offset, depths, "depth maps")
    return root


def test_tum_folder_associates_and_finds_missing_files(tmp_path: Path) -> None:
    root = _folder(tmp_path / "seq")
    folder = read_tum_folder(root, labels=True)
    assert len(folder.frames) == 4 and folder.unmatched_rgb == 0 and folder.groundtruth is None
    first = folder.frames[0]
    assert first.rgb == root / "rgb/10.000000.png" and first.depth == root / "depth/10.004000.png"
    assert first.labels == root / "labels/10.000000.png"
    assert first.depth_stamp - first.stamp == pytest.approx(0.004)
    assert all(folder.missing(f) is None for f in folder.frames)
    (root / "depth/10.037333.png").unlink()
    assert str(folder.missing(folder.frames[1])) == (
        f"{root / 'depth.txt'}:5: listed image depth/10.037333.png not found"
    )
    (root / "labels/10.066667.png").unlink()
    assert "label of rgb/10.066667.png not found (labels/ must mirror rgb/)" in str(
        folder.missing(folder.frames[2])
    )
    rgb_only = read_tum_folder(root, depth=False)
    assert rgb_only.depth is None and rgb_only.frames[1].depth is None
    assert rgb_only.frames[2].labels is None and rgb_only.missing(rgb_only.frames[1]) is None


def test_tum_folder_errors_name_the_path(tmp_path: Path) -> None:
    with pytest.raises(
        DataFormatError, match=r"nope: does not exist; expected a TUM sequence folder with"
    ):
        read_tum_folder(tmp_path / "nope")
    root = _folder(tmp_path / "seq", depth_offset=0.5)
    with pytest.raises(DataFormatError, match=r"depth\.txt: no depth stamp within 0\.02 s"):
        read_tum_folder(root)
    assert len(read_tum_folder(root, max_diff=0.6).frames) == 4
    (root / "depth.txt").unlink()
    with pytest.raises(DataFormatError, match=r"depth\.txt: not a TUM RGB-D sequence"):
        read_tum_folder(root)
    assert len(read_tum_folder(root, depth=False).frames) == 4
    (root / "rgb.txt").write_text("# nothing\n")
    with pytest.raises(DataFormatError, match=r"rgb\.txt: the sequence lists no images"):
        read_tum_folder(root, depth=False)


def test_the_label_of_a_jpeg_frame_is_the_png_of_its_stem(tmp_path: Path) -> None:
    """Labels are PNGs named as their colour frames: ``labels/x.png`` for ``rgb/x.jpg`` too."""
    from uss_slam.core.tum_io import label_file_name, read_tum_folder

    assert label_file_name("rgb/1.5.jpg") == label_file_name("1.5.png") == "1.5.png"
    (tmp_path / "rgb").mkdir()
    (tmp_path / "labels").mkdir()
    (tmp_path / "rgb" / "1.000000.jpg").write_bytes(b"a frame")
    (tmp_path / "labels" / "1.000000.png").write_bytes(b"its label")
    (tmp_path / "rgb.txt").write_text("# rgb\n1.000000 rgb/1.000000.jpg\n")
    folder = read_tum_folder(tmp_path, depth=False, labels=True)
    assert folder.frames[0].labels == tmp_path / "labels" / "1.000000.png"
    assert folder.missing(folder.frames[0]) is None


def test_a_frames_folder_that_cannot_be_searched_is_one_error_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``chmod 000 rgb`` (as a user, not root: ``stat`` of a file inside fails with EACCES):
    the error names the folder, not Python's ``PermissionError`` (uss-slam, uss-eval and
    uss-vocab check listed frames with :func:`is_file`)."""
    root = _folder(tmp_path / "seq")
    folder = read_tum_folder(root, labels=True)
    real = Path.is_file

    def denied(path: Path) -> bool:
        if path.parent.name == "rgb":
            raise PermissionError(13, "Permission denied", str(path))
        return real(path)

    monkeypatch.setattr(Path, "is_file", denied)
    with pytest.raises(DataFormatError, match="rgb: cannot be read: permission denied") as error:
        folder.missing(folder.frames[0])
    assert error.value.path == str(root / "rgb")

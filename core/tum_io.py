"""TUM RGB-D formats: image lists, trajectories, camera intrinsics and the sequence folder layout.
NumPy, SciPy (rotations) and YAML only.

The layout (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):

- ``rgb.txt`` / ``depth.txt``: ``timestamp filename`` per line, ``#`` starts a comment line;
- ``groundtruth.txt`` and estimated trajectories: ``timestamp tx ty tz qx qy qz qw``
  (camera-to-world, optical frame, metres, Hamilton quaternion with the scalar last);
- depth PNGs: uint16, ``DEPTH_SCALE`` = 5000 units per metre, 0 = no measurement.

Both the synthetic world (writer) and the SLAM harness (reader, never torch) use this module; the
camera intrinsics live in :mod:`.tum_camera` (re-exported here).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import DataFormatError
from .paths import input_folder, read_text
from .tum_camera import DEPTH_SCALE as DEPTH_SCALE
from .tum_camera import INTRINSICS_FILE as INTRINSICS_FILE
from .tum_camera import INTRINSICS_KEYS as INTRINSICS_KEYS
from .tum_camera import KINECT_READOUT as KINECT_READOUT
from .tum_camera import TUM_CAMERAS as TUM_CAMERAS
from .tum_camera import CameraIntrinsics as CameraIntrinsics
from .tum_camera import StrPath as StrPath
from .tum_camera import resolve_camera as resolve_camera

UNIT_QUATERNION_TOL = 1e-3
"""Largest accepted deviation of a trajectory quaternion's norm from 1 (files hold 4 decimals)."""


# --------------------------------------------------------------------------- rotations


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from quaternions ``(..., 4)`` ordered ``qx qy qz qw``
    (Hamilton, scalar last: scipy's order); normalised first."""
    q = np.asarray(q, dtype=np.float64)
    flat = q.reshape(-1, 4)
    if len(flat) == 0:
        return np.zeros(q.shape[:-1] + (3, 3))
    return Rotation.from_quat(flat).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` (``qx qy qz qw``, ``qw >= 0``) from rotations ``(..., 3, 3)``."""
    r = np.asarray(r, dtype=np.float64)
    flat = r.reshape(-1, 3, 3)
    if len(flat) == 0:
        return np.zeros(r.shape[:-2] + (4,))
    q = Rotation.from_matrix(flat).as_quat()
    q[q[:, 3] < 0] *= -1.0  # the sign TUM files use; a 180-degree turn (qw = 0) keeps scipy's
    return q.reshape(r.shape[:-2] + (4,))


# --------------------------------------------------------------------------- parsing helpers


def _data_lines(path: Path) -> list[tuple[int, list[str]]]:
    """``(line number, fields)`` of every non-comment, non-blank line; fields split on spaces/commas."""
    text = read_text(path)
    rows = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        rows.append((number, line.replace(",", " ").replace("\t", " ").split()))
    return rows


def _float(path: Path, line: int, text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DataFormatError(path, f"expected a number for {what}, got {text!r}", line) from None
    if not math.isfinite(value):
        raise DataFormatError(path, f"expected a finite number for {what}, got {text!r}", line)
    return value


def _check_increasing(path: Path, lines: Sequence[int], stamps: np.ndarray) -> None:
    for k in range(1, len(stamps)):
        if stamps[k] == stamps[k - 1]:
            raise DataFormatError(
                path, f"duplicate timestamp {stamps[k]:.6f} (also on line {lines[k - 1]})", lines[k]
            )
        if stamps[k] < stamps[k - 1]:
            raise DataFormatError(
                path,
                f"timestamps must increase: {stamps[k]:.6f} after {stamps[k - 1]:.6f} "
                f"(line {lines[k - 1]})",
                lines[k],
            )


# --------------------------------------------------------------------------- image lists


@dataclass(frozen=True)
class FileList:
    """An ``rgb.txt`` / ``depth.txt`` list: stamps (seconds) and paths relative to its folder."""

    path: Path
    stamps: np.ndarray
    files: tuple[str, ...]
    lines: tuple[int, ...] = ()  # 1-based line of each entry in the file (for error messages)

    def __len__(self) -> int:
        return len(self.files)

    def resolve(self, index: int) -> Path:
        """Absolute path of entry ``index`` (relative to the list file's folder)."""
        return self.path.parent / self.files[index]


def read_file_list(path: StrPath, *, skipped: list[DataFormatError] | None = None) -> FileList:
    """Read ``rgb.txt`` / ``depth.txt``: ``timestamp filename`` lines, strictly increasing stamps.

    A bad line raises :class:`DataFormatError` (file and line); when a ``skipped`` list is given,
    such lines (and lines whose stamp does not increase) are left out and their errors appended.
    """
    path = Path(path)
    stamps: list[float] = []
    files: list[str] = []
    lines: list[int] = []
    for number, fields in _data_lines(path):
        try:
            if len(fields) != 2:
                raise DataFormatError(
                    path,
                    f"expected 'timestamp filename' (2 columns), got {len(fields)} columns",
                    number,
                )
            stamp = _float(path, number, fields[0], "the timestamp")
            if skipped is not None and stamps and stamp <= stamps[-1]:
                _check_increasing(path, [lines[-1], number], np.array([stamps[-1], stamp]))
        except DataFormatError as error:
            if skipped is None:
                raise
            skipped.append(error)
            continue
        stamps.append(stamp)
        files.append(fields[1])
        lines.append(number)
    array = np.asarray(stamps, dtype=np.float64)
    _check_increasing(path, lines, array)
    return FileList(path=path, stamps=array, files=tuple(files), lines=tuple(lines))


def write_file_list(
    path: StrPath, stamps: Sequence[float], files: Sequence[str], kind: str = "color images"
) -> None:
    """Write an image list with TUM's three header comment lines."""
    if len(stamps) != len(files):
        raise ValueError(f"{len(stamps)} stamps but {len(files)} files")
    lines = [f"# {kind}", "# file: 'uss-slam synthetic'", "# timestamp filename"]
    lines += [f"{s:.6f} {f}" for s, f in zip(stamps, files, strict=True)]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def associate(
    first: np.ndarray, second: np.ndarray, max_difference: float = 0.02, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Match two stamp lists as TUM's ``associate.py`` does (rgb to depth, for instance).

    Candidate pairs with ``|a - (b + offset)| < max_difference`` are taken greedily by increasing
    difference, each stamp used at most once. Returns index arrays ``(i, j)`` sorted by ``i``.
    """
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64) + offset
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # Stamps are sorted; only the neighbours of each insertion point can be within reach, but the
    # greedy order needs all candidates within max_difference, so collect them by window.
    lo = np.searchsorted(b, a - max_difference, side="left")
    hi = np.searchsorted(b, a + max_difference, side="right")
    cand_i, cand_j = [], []
    for i in range(len(a)):
        for j in range(lo[i], hi[i]):
            if abs(a[i] - b[j]) < max_difference:
                cand_i.append(i)
                cand_j.append(j)
    ci = np.asarray(cand_i, dtype=np.int64)
    cj = np.asarray(cand_j, dtype=np.int64)
    diff = np.abs(a[ci] - b[cj]) if len(ci) else np.zeros(0)
    order = np.lexsort((cj, ci, diff))
    used_a = np.zeros(len(a), dtype=bool)
    used_b = np.zeros(len(b), dtype=bool)
    out_i, out_j = [], []
    for k in order:
        i, j = ci[k], cj[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            out_i.append(i)
            out_j.append(j)
    sort = np.argsort(out_i, kind="stable")
    return np.asarray(out_i, dtype=np.int64)[sort], np.asarray(out_j, dtype=np.int64)[sort]


# --------------------------------------------------------------------------- trajectories


@dataclass(frozen=True)
class Trajectory:
    """Timed camera-to-world poses.

    ``stamps`` (N,) seconds; ``positions`` (N, 3) metres; ``quaternions`` (N, 4) ``qx qy qz qw``.
    """

    stamps: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    path: Path | None = field(default=None, compare=False)

    def __len__(self) -> int:
        return len(self.stamps)

    @classmethod
    def from_matrices(cls, stamps: Sequence[float], poses: np.ndarray) -> Trajectory:
        """From ``(N, 4, 4)`` camera-to-world matrices."""
        poses = np.asarray(poses, dtype=np.float64)
        return cls(
            stamps=np.asarray(stamps, dtype=np.float64),
            positions=poses[:, :3, 3].copy(),
            quaternions=matrix_to_quat(poses[:, :3, :3]),
        )

    def matrices(self) -> np.ndarray:
        """``(N, 4, 4)`` camera-to-world homogeneous matrices."""
        out = np.tile(np.eye(4), (len(self), 1, 1))
        out[:, :3, :3] = quat_to_matrix(self.quaternions)
        out[:, :3, 3] = self.positions
        return out


def read_trajectory(path: StrPath) -> Trajectory:
    """Read ``timestamp tx ty tz qx qy qz qw`` lines, checking every line.

    Raises :class:`DataFormatError` naming the line for a wrong column count, a non-numeric
    value, a quaternion whose norm is not 1 (within ``UNIT_QUATERNION_TOL``), or stamps that are
    not strictly increasing.
    """
    path = Path(path)
    rows: list[list[float]] = []
    lines: list[int] = []
    names = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
    for number, fields in _data_lines(path):
        if len(fields) != 8:
            raise DataFormatError(
                path,
                f"expected 8 columns 'timestamp tx ty tz qx qy qz qw', got {len(fields)}",
                number,
            )
        row = [_float(path, number, text, name) for text, name in zip(fields, names, strict=True)]
        norm = math.sqrt(sum(v * v for v in row[4:]))
        if abs(norm - 1.0) > UNIT_QUATERNION_TOL:
            raise DataFormatError(
                path, f"quaternion (qx qy qz qw) must have unit norm, got norm {norm:.6f}", number
            )
        rows.append(row)
        lines.append(number)
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 8)
    _check_increasing(path, lines, data[:, 0])
    quats = (
        data[:, 4:8] / np.linalg.norm(data[:, 4:8], axis=1, keepdims=True)
        if len(data)
        else data[:, 4:8]
    )
    return Trajectory(stamps=data[:, 0], positions=data[:, 1:4], quaternions=quats, path=path)


def write_trajectory(path: StrPath, trajectory: Trajectory, comment: str | None = None) -> None:
    """Write TUM trajectory lines (stamps to 6 decimals, poses to 7)."""
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    if comment:
        lines.insert(0, f"# {comment}")
    for s, p, q in zip(
        trajectory.stamps, trajectory.positions, trajectory.quaternions, strict=True
    ):
        lines.append(f"{s:.6f} " + " ".join(f"{v:.7f}" for v in (*p, *q)))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


# --------------------------------------------------------------------------- sequence folders

RGB_LIST = "rgb.txt"
DEPTH_LIST = "depth.txt"
GROUNDTRUTH_FILE = "groundtruth.txt"
LABELS_DIR = "labels"


def is_file(path: Path) -> bool:
    """``path.is_file()``, except that a folder on the way whose mode forbids looking inside it
    (``chmod 000 rgb``) is an error naming that folder, not Python's ``PermissionError``."""
    try:
        return path.is_file()
    except PermissionError:
        raise DataFormatError(
            path.parent, "cannot be read: permission denied (its mode forbids looking inside it)"
        ) from None


def label_file_name(rgb_name: str) -> str:
    """The name of a colour frame's label image: a PNG (labels are lossless) with the frame's
    stem, ``x.png`` for ``rgb/x.png`` and for ``rgb/x.jpg`` alike."""
    return Path(rgb_name).stem + ".png"


@dataclass(frozen=True)
class FrameFiles:
    """One colour frame of a sequence folder with its partners (absolute paths, seconds).

    ``rgb_index`` / ``depth_index`` are the entries of ``rgb.txt`` / ``depth.txt``; ``depth``
    fields are None when the folder was read without depth, ``labels`` when without labels.
    """

    stamp: float
    rgb: Path
    rgb_index: int
    depth_stamp: float | None = None
    depth: Path | None = None
    depth_index: int | None = None
    labels: Path | None = None


@dataclass(frozen=True)
class TumFolder:
    """The file layout of a TUM RGB-D sequence folder (see :func:`read_tum_folder`)."""

    root: Path
    rgb: FileList
    depth: FileList | None
    frames: tuple[FrameFiles, ...]
    unmatched_rgb: int
    """Colour frames without a depth frame within ``max_diff`` (left out of ``frames``)."""

    @property
    def groundtruth(self) -> Path | None:
        """``groundtruth.txt`` when the folder has one."""
        path = self.root / GROUNDTRUTH_FILE
        return path if is_file(path) else None

    def missing(self, frame: FrameFiles) -> DataFormatError | None:
        """The error for the first file of ``frame`` that does not exist (None: all there);
        it names the list file and line that lists the missing image."""
        for files, index, path in (
            (self.rgb, frame.rgb_index, frame.rgb),
            (self.depth, frame.depth_index, frame.depth),
        ):
            if files is None or index is None or path is None or is_file(path):
                continue
            line = files.lines[index] if files.lines else None
            return DataFormatError(files.path, f"listed image {files.files[index]} not found", line)
        if frame.labels is not None and not is_file(frame.labels):
            return DataFormatError(
                frame.labels,
                f"label of {self.rgb.files[frame.rgb_index]} not found "
                f"({LABELS_DIR}/ must mirror rgb/)",
            )
        return None


def read_tum_folder(
    root: StrPath,
    *,
    depth: bool = True,
    labels: bool = False,
    max_diff: float = 0.02,
    skipped: list[DataFormatError] | None = None,
) -> TumFolder:
    """Read a sequence folder's lists: ``rgb.txt``, with ``depth`` also ``depth.txt`` associated
    to it as TUM's ``associate.py`` does (nearest stamp within ``max_diff`` seconds), with
    ``labels`` the ``labels/`` file of every colour frame.

    Missing folders and lists, lists without entries, no association at all: a
    :class:`DataFormatError` naming the path. Bad list lines too, unless ``skipped`` is given
    (they are then left out and their errors appended, see :func:`read_file_list`). Whether the
    listed images exist is :meth:`TumFolder.missing`'s business, for the frames one uses.
    """
    root = Path(os.path.expanduser(root))
    needed = f"{RGB_LIST} and {DEPTH_LIST}" if depth else RGB_LIST
    input_folder(root, None, f"expected a TUM sequence folder with {needed}")
    lists = [RGB_LIST, DEPTH_LIST] if depth else [RGB_LIST]
    for name in lists:
        if not is_file(root / name):
            raise DataFormatError(root / name, f"not a TUM RGB-D sequence: {name} not found")
    rgb = read_file_list(root / RGB_LIST, skipped=skipped)
    if len(rgb) == 0:
        raise DataFormatError(rgb.path, "the sequence lists no images")
    labels_dir = root / LABELS_DIR
    if labels and not labels_dir.is_dir():
        raise DataFormatError(
            labels_dir,
            "labels requested but the folder does not exist (uint8 class-id PNGs named as the "
            "rgb/ files)",
        )

    def label(index: int) -> Path | None:
        return labels_dir / label_file_name(rgb.files[index]) if labels else None

    if not depth:
        frames = tuple(
            FrameFiles(float(rgb.stamps[k]), rgb.resolve(k), k, labels=label(k))
            for k in range(len(rgb))
        )
        return TumFolder(root, rgb, None, frames, 0)
    depths = read_file_list(root / DEPTH_LIST, skipped=skipped)
    i, j = associate(rgb.stamps, depths.stamps, max_difference=max_diff)
    if len(i) == 0:
        raise DataFormatError(
            depths.path,
            f"no depth stamp within {max_diff} s of any stamp in {rgb.path.name} "
            "(rgb and depth do not associate)",
        )
    frames = tuple(
        FrameFiles(
            float(rgb.stamps[a]),
            rgb.resolve(a),
            a,
            float(depths.stamps[b]),
            depths.resolve(b),
            b,
            label(a),
        )
        for a, b in zip(i.tolist(), j.tolist(), strict=True)
    )
    return TumFolder(root, rgb, depths, frames, len(rgb) - len(i))

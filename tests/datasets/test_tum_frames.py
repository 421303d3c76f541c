"""TUM-layout frame dataset (target domain), optional labels/ for validation."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from uss_slam.core.errors import DataFormatError
from uss_slam.core.tum_io import write_file_list
from uss_slam.datasets.tum import TUMFrames

torch.set_num_threads(1)


def write_sequence(root: Path, frames: int = 5, size: tuple[int, int] = (32, 24)) -> Path:
    """A TUM RGB-D sequence folder with rgb/, labels/ and rgb.txt (depth omitted)."""
    (root / "rgb").mkdir(parents=True)
    (root / "labels").mkdir()
    width, height = size
    stamps = [1305031102.175304 + i / 30 for i in range(frames)]
    files = []
    for i, stamp in enumerate(stamps):
        name = f"{stamp:.6f}.png"
        files.append(f"rgb/{name}")
        cv2.imwrite(str(root / "rgb" / name), np.full((height, width, 3), 10 * i, np.uint8))
        label = np.zeros((height, width), np.uint8)
        label[:, : i + 1] = i % 4
        cv2.imwrite(str(root / "labels" / name), label)
    write_file_list(root / "rgb.txt", stamps, files)
    return root


def test_frames_with_and_without_labels(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "walking")
    unlabelled = TUMFrames(root)
    assert len(unlabelled) == 5 and not unlabelled.labelled
    sample = unlabelled[2]
    assert set(sample) == {"image", "name"}
    assert sample["image"].shape == (3, 24, 32)
    assert sample["name"] == "walking/1305031102.241971"
    labelled = TUMFrames([root, root], labels=True, stride=2)
    assert len(labelled) == 6 and labelled.labelled
    label = labelled[1]["label"]
    assert label.dtype == torch.int64 and label.shape == (24, 32)
    assert label[0, :3].tolist() == [2, 2, 2] and label[0, 3] == 0  # frame 2


def test_missing_pieces_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match=r"rgb\.txt: not a TUM RGB-D sequence"):
        TUMFrames(tmp_path)
    root = write_sequence(tmp_path / "seq")
    files = sorted((root / "labels").iterdir())
    files[1].unlink()
    with pytest.raises(DataFormatError, match="labels/ must mirror rgb/"):
        TUMFrames(root, labels=True)
    assert len(TUMFrames(root)) == 5  # unlabelled use does not need labels/
    sorted((root / "rgb").iterdir())[0].unlink()
    with pytest.raises(DataFormatError, match=r"rgb\.txt:\d+: listed image rgb/.*\.png not found"):
        TUMFrames(root)


def test_label_values_outside_the_project_classes_are_rejected(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "seq", frames=1)
    (label_file,) = (root / "labels").iterdir()
    cv2.imwrite(str(label_file), np.full((24, 32), 7, np.uint8))
    with pytest.raises(DataFormatError, match=r"label values 7 are not class ids; expected 0\.\.3"):
        TUMFrames(root, labels=True)[0]


@pytest.mark.parametrize("kind", ["jpeg", "cut"])
def test_a_label_the_one_label_reader_refuses_is_refused_by_training_too(
    tmp_path: Path, kind: str
) -> None:
    """The data sets read labels through the project's one label reader: a grey JPEG named
    ``.png`` (lossy class ids; PIL read it as labels) and a PNG cut short are one line naming
    the file, as in ``uss-eval`` and ``uss-slam``."""
    root = write_sequence(tmp_path / "seq", frames=1)
    (label_file,) = (root / "labels").iterdir()
    if kind == "jpeg":
        label_file.write_bytes(cv2.imencode(".jpg", np.zeros((24, 32), np.uint8))[1].tobytes())
        says = "its content is a JPEG image, not the PNG its name says"
    else:
        label_file.write_bytes(label_file.read_bytes()[:-20])
        says = "truncated PNG"
    with pytest.raises(DataFormatError, match=f"{label_file.name}: {says}"):
        TUMFrames(root, labels=True)[0]

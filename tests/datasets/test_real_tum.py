"""TUM RGB-D target frames: several sequences, stride, held-out frames, exclusions, bad lists."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf
from realdata_helpers import write_tum

from uss_slam.core.errors import DataFormatError
from uss_slam.core.schema import SchemaError, check_target
from uss_slam.core.tum_io import read_file_list
from uss_slam.datasets.tum import TUMFrames

torch.set_num_threads(1)


def _stamps(dataset: TUMFrames) -> list[str]:
    return [item.name for item in dataset.items]


def _names(root: Path, indices: list[int]) -> list[str]:
    frames = read_file_list(root / "rgb.txt")
    return [f"{root.name}/{frames.stamps[i]:.6f}" for i in indices]


@pytest.fixture
def sequences(tmp_path: Path) -> list[Path]:
    return [write_tum(tmp_path / "walking_xyz", 20), write_tum(tmp_path / "sitting_static", 8)]


def test_several_sequences_with_stride_need_no_depth(sequences: list[Path]) -> None:
    xyz, static = sequences
    assert not (xyz / "depth.txt").exists() and not (xyz / "depth").exists()
    dataset = TUMFrames([str(xyz), str(static)], stride=3)
    assert _stamps(dataset) == _names(xyz, [0, 3, 6, 9, 12, 15, 18]) + _names(static, [0, 3, 6])
    assert all(item.label is None for item in dataset.items) and not dataset.labelled
    sample = dataset[7]
    assert set(sample) == {"image", "name"} and sample["image"].shape == (3, 24, 32)
    assert sample["name"] == _names(static, [0])[0]
    assert len(TUMFrames(xyz)) == 20


def test_held_out_frames_are_the_end_of_each_sequence(sequences: list[Path]) -> None:
    xyz, static = sequences
    train = TUMFrames(sequences, holdout=0.25)  # 5 of 20 and 2 of 8 frames held out
    held = TUMFrames(sequences, holdout=0.25, part="holdout")
    assert _stamps(train) == _names(xyz, list(range(15))) + _names(static, list(range(6)))
    assert _stamps(held) == _names(xyz, list(range(15, 20))) + _names(static, [6, 7])
    gap = TUMFrames(sequences, holdout=0.25, holdout_gap=2, stride=2)
    assert _stamps(gap) == _names(xyz, [0, 2, 4, 6, 8, 10, 12]) + _names(static, [0, 2])
    assert not set(_stamps(gap)) & set(_stamps(held))
    with pytest.raises(ValueError, match="part='holdout' needs holdout > 0"):
        TUMFrames(xyz, part="holdout")
    # the ranges are the config's schema: data.<split>.holdout=1 is one line naming the key
    node = OmegaConf.create({"_target_": "uss_slam.datasets.tum.TUMFrames", "holdout": 1.0})
    with pytest.raises(SchemaError, match=r"^data\.val\.holdout: expected a number >= 0 and < 1"):
        check_target(node, "data.val")


def test_frames_labelled_for_validation_are_excluded(sequences: list[Path], tmp_path: Path) -> None:
    xyz, static = sequences
    frames = read_file_list(xyz / "rgb.txt")
    export = tmp_path / "labels.json"  # a CVAT export of two frames (file_name with folders)
    images = [
        {"id": k, "file_name": frames.files[i], "width": 32, "height": 24}
        for k, i in enumerate((1, 4))
    ]
    export.write_text(json.dumps({"images": images, "annotations": [], "categories": []}))
    listing = tmp_path / "frames.txt"
    listing.write_text(f"# labelled by hand\n{frames.stamps[2]:.6f} {frames.files[2]}\n")
    dataset = TUMFrames(xyz, exclude=[export, listing])
    assert _stamps(dataset) == _names(xyz, [0, 3] + list(range(5, 20)))
    listing.write_text("a b c\n")
    with pytest.raises(DataFormatError, match=r"frames\.txt:1: expected 'file' or 'timestamp"):
        TUMFrames(xyz, exclude=[listing])
    export.write_text('{"images": [{"id": 1}]}')
    with pytest.raises(DataFormatError, match=r"labels\.json: expected a COCO JSON"):
        TUMFrames(xyz, exclude=[export])
    with pytest.raises(DataFormatError, match=r"missing\.txt: frame list not found"):
        TUMFrames(xyz, exclude=[tmp_path / "missing.txt"])


def test_bad_rgb_txt_lines_raise_or_are_skipped(sequences: list[Path]) -> None:
    xyz = sequences[0]
    lines = (xyz / "rgb.txt").read_text().splitlines()
    header = sum(line.startswith("#") for line in lines)
    data = lines[header:]
    data[2] = "1305031102.2 rgb/a.png extra"  # 3 columns
    data[5] = "yesterday rgb/b.png"  # no timestamp
    data[8] = data[7]  # duplicate timestamp
    (xyz / "rgb.txt").write_text("\n".join(lines[:header] + data) + "\n")
    with pytest.raises(
        DataFormatError, match=rf"rgb\.txt:{header + 3}: expected 'timestamp filename'"
    ):
        TUMFrames(xyz)
    dataset = TUMFrames(xyz, on_error="skip")
    assert len(dataset) == 17 and len(dataset.skipped) == 3
    assert [e.line for e in dataset.skipped] == [header + 3, header + 6, header + 9]
    assert "expected a number for the timestamp, got 'yesterday'" in str(dataset.skipped[1])
    assert "duplicate timestamp" in str(dataset.skipped[2])


def test_missing_images_and_sequences(sequences: list[Path], tmp_path: Path) -> None:
    xyz = sequences[0]
    frames = read_file_list(xyz / "rgb.txt")
    frames.resolve(3).unlink()
    line = frames.lines[3]
    with pytest.raises(DataFormatError, match=rf"rgb\.txt:{line}: listed image {frames.files[3]}"):
        TUMFrames(xyz)
    skipping = TUMFrames(xyz, on_error="skip")
    assert len(skipping) == 19 and len(skipping.skipped) == 1
    with pytest.raises(
        DataFormatError, match=r"nowhere: does not exist; expected a TUM sequence folder"
    ):
        TUMFrames([sequences[1], tmp_path / "nowhere"])
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "rgb.txt").write_text("# timestamp filename\n")
    with pytest.raises(DataFormatError, match=r"rgb\.txt: the sequence lists no images"):
        TUMFrames(tmp_path / "empty")
    with pytest.raises(DataFormatError, match=r"labels: labels requested but the folder does"):
        TUMFrames(sequences[1], labels=True)


def test_tum_io_stays_torch_free() -> None:
    """slam_eval imports tum_io and must never import torch (not even indirectly)."""
    code = "import sys, uss_slam.core.tum_io; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_truncated_or_unreadable_frames_are_found_before_training(sequences: list[Path]) -> None:
    xyz = sequences[0]
    frames = read_file_list(xyz / "rgb.txt")
    png = frames.resolve(4)
    png.write_bytes(png.read_bytes()[:-40])
    frames.resolve(7).write_bytes(b"not an image")
    with pytest.raises(DataFormatError, match=rf"{png.name}: truncated PNG"):
        TUMFrames(xyz)
    skipping = TUMFrames(xyz, on_error="skip")
    assert len(skipping) == 18
    assert [Path(e.path).name for e in skipping.skipped] == [png.name, frames.resolve(7).name]
    assert "cannot read image" in str(skipping.skipped[1])

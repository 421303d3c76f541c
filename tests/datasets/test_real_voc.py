"""PASCAL VOC 2012 on a devkit-format fixture: splits, remapped classes, every bad input."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import torch
from realdata_helpers import paint_voc, standard_scenes, write_voc

from uss_slam.core.classes import voc_lut
from uss_slam.core.errors import DataFormatError
from uss_slam.datasets.voc import VOCSegmentation

torch.set_num_threads(1)
SHAPE = (40, 48)


def _labels() -> dict[str, np.ndarray]:
    return {name: paint_voc(SHAPE, scene) for name, scene in standard_scenes(SHAPE).items()}


@pytest.fixture
def voc(tmp_path: Path) -> Path:
    names = list(_labels())
    return write_voc(tmp_path, _labels(), {"train": names[:3], "val": names[3:], "trainval": names})


def test_splits_pairs_and_remapped_classes(voc: Path) -> None:
    labels = _labels()
    for split, expected in (("train", 3), ("val", 2), ("trainval", 5)):
        dataset = VOCSegmentation(voc.parent.parent, split=split)  # the folder holding VOCdevkit
        assert len(dataset) == expected and dataset.skipped == []
        for index, item in enumerate(dataset.items):
            assert item.image == voc / "JPEGImages" / f"{item.name}.jpg"
            assert item.label == voc / "SegmentationClass" / f"{item.name}.png"
            np.testing.assert_array_equal(dataset.read_label(index), voc_lut()[labels[item.name]])
    sample = VOCSegmentation(voc, split="train")[0]
    assert sample["name"] == "2008_000001" and sample["label"].shape == SHAPE
    # person (15) over the monitor (20), chair (9), crowd void (255); the dog (12) -> background
    assert set(torch.unique(sample["label"]).tolist()) == {0, 1, 2, 3, 255}
    assert VOCSegmentation(voc, split="val").read_label(1).max() == 0  # only a dog


@pytest.mark.parametrize("missing", ["label", "image", "both"])
def test_listed_id_without_its_files_names_list_file_and_line(voc: Path, missing: str) -> None:
    if missing in ("label", "both"):
        (voc / "SegmentationClass" / "2008_000002.png").unlink()
    if missing in ("image", "both"):
        (voc / "JPEGImages" / "2008_000002.jpg").unlink()
    why = {
        "label": r"2008_000002\.png \(listed as '2008_000002'\) not found: the image "
        r"2008_000002\.jpg has no label",
        "image": r"2008_000002\.jpg \(listed as '2008_000002'\) not found: the label "
        r"2008_000002\.png has no image",
        "both": r"neither image nor label exists",
    }[missing]
    with pytest.raises(DataFormatError, match=rf"Segmentation/train\.txt:2: .*{why}"):
        VOCSegmentation(voc, split="train")
    skipping = VOCSegmentation(voc, split="train", on_error="skip")
    assert [item.name for item in skipping.items] == ["2008_000001", "2008_000003"]
    assert len(skipping.skipped) == 1 and skipping.skipped[0].line == 2


def test_skipped_items_are_logged(voc: Path, caplog: pytest.LogCaptureFixture) -> None:
    (voc / "SegmentationClass" / "2008_000002.png").unlink()
    (voc / "JPEGImages" / "2008_000003.jpg").unlink()
    with caplog.at_level(logging.WARNING):
        VOCSegmentation(voc, split="train", on_error="skip")
    assert "skipped 2 bad input(s) (on_error=skip)" in caplog.text
    assert "train.txt:2:" in caplog.text and "train.txt:3:" in caplog.text


def test_bad_split_lists(voc: Path) -> None:
    lists = voc / "ImageSets" / "Segmentation"
    (lists / "empty.txt").write_text("\n\n")
    with pytest.raises(DataFormatError, match=r"empty\.txt: the split list is empty"):
        VOCSegmentation(voc, split="empty")
    (lists / "twice.txt").write_text("2008_000001\n2008_000002\n2008_000001\n")
    with pytest.raises(DataFormatError, match=r"twice\.txt:3: id '2008_000001' listed twice"):
        VOCSegmentation(voc, split="twice")
    (lists / "main.txt").write_text("2008_000001  1\n")  # an ImageSets/Main list by mistake
    with pytest.raises(DataFormatError, match=r"main\.txt:1: expected one image id per line"):
        VOCSegmentation(voc, split="main")
    with pytest.raises(DataFormatError, match=r"test\.txt: split list for split 'test' not found"):
        VOCSegmentation(voc, split="test")
    with pytest.raises(ValueError, match="on_error must be one of"):
        VOCSegmentation(voc, on_error="ignore")  # type: ignore[arg-type]


def test_corrupt_and_truncated_files_name_the_file(voc: Path) -> None:
    dataset = VOCSegmentation(voc, split="train")
    jpeg = voc / "JPEGImages" / "2008_000001.jpg"
    jpeg.write_bytes(jpeg.read_bytes()[:-200])
    with pytest.raises(DataFormatError, match=r"2008_000001\.jpg: truncated JPEG"):
        dataset[0]
    jpeg.write_bytes(b"not a jpeg at all")
    with pytest.raises(
        DataFormatError, match=r"2008_000001\.jpg: not a readable image; expected a colour image"
    ):
        dataset[0]
    png = voc / "SegmentationClass" / "2008_000002.png"
    intact = png.read_bytes()
    png.write_bytes(intact[:-20])  # pixel data complete, IEND lost: still a truncated file
    truncated = r"2008_000002\.png: truncated PNG: .*\(no IEND chunk\)"
    with pytest.raises(DataFormatError, match=truncated):
        dataset[1]
    png.write_bytes(intact[:40] + bytes(len(intact) - 60) + intact[-20:])  # damaged inside
    with pytest.raises(DataFormatError, match=r"2008_000002\.png: corrupt PNG: "):
        dataset[1]


def test_data_after_the_end_of_a_complete_file_is_accepted(voc: Path) -> None:
    """Some cameras and editors append bytes after JPEG's FFD9 / PNG's IEND."""
    dataset = VOCSegmentation(voc, split="train")
    expected = dataset[0]
    for path in (
        voc / "JPEGImages" / "2008_000001.jpg",
        voc / "SegmentationClass" / "2008_000001.png",
    ):
        path.write_bytes(path.read_bytes() + bytes(100) + b"trailer")
    sample = dataset[0]
    assert torch.equal(sample["image"], expected["image"])
    assert torch.equal(sample["label"], expected["label"])
    assert dataset.check_image(0, *SHAPE) is None


def test_label_values_outside_the_palette_and_wrong_sizes(voc: Path) -> None:
    labels = _labels()
    bad = labels["2008_000003"].copy()
    bad[0, :3] = [21, 100, 254]  # no VOC index (0..20) nor void (255)
    write_voc(voc.parent.parent, {"2008_000003": bad}, {})
    dataset = VOCSegmentation(voc, split="train")
    with pytest.raises(DataFormatError, match=r"2008_000003\.png: label values \[21, 100, 254\]"):
        dataset[2]
    write_voc(voc.parent.parent, {"2008_000003": np.zeros((20, 48), np.uint8)}, {})
    (voc / "SegmentationClass" / "2008_000003.png").write_bytes(
        (voc / "SegmentationClass" / "2008_000001.png").read_bytes()
    )
    with pytest.raises(
        DataFormatError, match=r"2008_000003\.png: label is 48×40 but its image 2008_000003\.jpg"
    ):
        dataset[2]

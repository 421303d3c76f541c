"""VOC-layout segmentation dataset: real devkit file format, class remap, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from uss_slam.core.classes import IGNORE_INDEX, voc_palette
from uss_slam.core.errors import DataFormatError
from uss_slam.datasets.transforms import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.datasets.voc import VOCSegmentation

torch.set_num_threads(1)


def write_voc(root: Path, labels: dict[str, np.ndarray], split: str = "train") -> Path:
    """A VOC2012 tree in the devkit format: JPEG images, palette PNG labels, split list."""
    voc = root / "VOCdevkit" / "VOC2012"
    for sub in ("JPEGImages", "SegmentationClass", "ImageSets/Segmentation"):
        (voc / sub).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for name, label in labels.items():
        rgb = rng.integers(0, 256, (*label.shape, 3), dtype=np.uint8)
        Image.fromarray(rgb).save(voc / "JPEGImages" / f"{name}.jpg", quality=95)
        png = Image.fromarray(label, mode="P")
        png.putpalette(voc_palette().tobytes())
        png.save(voc / "SegmentationClass" / f"{name}.png")
    (voc / "ImageSets" / "Segmentation" / f"{split}.txt").write_text("\n".join(labels) + "\n")
    return voc


def _label() -> np.ndarray:
    label = np.zeros((24, 32), dtype=np.uint8)
    label[2:6, :] = 15  # person
    label[6:10, :] = 9  # chair
    label[10:14, :] = 20  # tvmonitor
    label[14:18, :] = 12  # dog -> background
    label[18:20, :] = 255  # void border
    return label


def test_voc_indices_are_remapped_to_project_classes(tmp_path: Path) -> None:
    voc = write_voc(tmp_path, {"2007_000001": _label()})
    for root in (voc, tmp_path):  # the VOC2012 folder itself or a parent of VOCdevkit
        dataset = VOCSegmentation(root, split="train")
        assert len(dataset) == 1 and dataset.labelled
        sample = dataset[0]
        label = sample["label"]
        assert label.dtype == torch.int64 and label.shape == (24, 32)
        assert label[0, 0] == 0 and label[3, 5] == 1 and label[7, 5] == 2 and label[11, 5] == 3
        assert label[15, 5] == 0 and label[19, 5] == IGNORE_INDEX
        assert sample["name"] == "2007_000001"
        image = sample["image"]
        assert image.dtype == torch.float32 and image.shape == (3, 24, 32)
        # Default transform = ImageNet normalisation of [0, 1] pixels.
        low = (0 - np.array(IMAGENET_MEAN)) / np.array(IMAGENET_STD)
        high = (1 - np.array(IMAGENET_MEAN)) / np.array(IMAGENET_STD)
        for c in range(3):
            assert low[c] - 1e-5 <= image[c].min() and image[c].max() <= high[c] + 1e-5


def test_missing_files_are_reported_with_list_file_and_line(tmp_path: Path) -> None:
    voc = write_voc(tmp_path, {"a": _label(), "b": _label()})
    (voc / "SegmentationClass" / "b.png").unlink()
    with pytest.raises(
        DataFormatError, match=r"train\.txt:2: .*b\.png \(listed as 'b'\) not found"
    ):
        VOCSegmentation(voc)
    with pytest.raises(DataFormatError, match=r"val\.txt: split list for split 'val' not found"):
        VOCSegmentation(voc, split="val")
    with pytest.raises(DataFormatError, match="nowhere: not a VOC tree: the folder does not exist"):
        VOCSegmentation(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match="empty: not a VOC tree: expected ImageSets"):
        VOCSegmentation(tmp_path / "empty")


def test_rgb_labels_and_non_voc_indices_are_rejected(tmp_path: Path) -> None:
    voc = write_voc(tmp_path, {"a": _label()})
    label_path = voc / "SegmentationClass" / "a.png"
    Image.fromarray(np.zeros((24, 32, 3), dtype=np.uint8)).save(label_path)
    with pytest.raises(
        DataFormatError, match=r"a\.png: expected a single-channel .* \(24, 32, 3\)"
    ):
        VOCSegmentation(voc)[0]
    bad = _label()
    bad[0, 0] = 42
    write_voc(tmp_path, {"a": bad})
    with pytest.raises(DataFormatError, match=r"a\.png: label values \[42\]"):
        VOCSegmentation(voc)[0]


def test_label_and_image_sizes_must_match(tmp_path: Path) -> None:
    voc = write_voc(tmp_path, {"a": _label()})
    Image.fromarray(np.zeros((10, 10, 3), dtype=np.uint8)).save(voc / "JPEGImages" / "a.jpg")
    with pytest.raises(
        DataFormatError, match=r"a\.png: label is 32×24 but its image a\.jpg is 10×10"
    ):
        VOCSegmentation(voc)[0]


def test_an_exif_orientation_tag_leaves_the_stored_pixels_aligned_with_the_label(
    tmp_path: Path,
) -> None:
    """VOC's labels are aligned with a JPEG's stored pixels: an EXIF orientation tag (6: rotate
    90 degrees to display) is not applied, so the 32x24 image still matches its 32x24 label."""
    voc = write_voc(tmp_path, {"a": _label()})
    path = voc / "JPEGImages" / "a.jpg"
    with Image.open(path) as image:
        stored = np.asarray(image.convert("RGB"))
        exif = Image.Exif()
        exif[0x0112] = 6
        image.save(path, exif=exif, quality=95)
    sample = VOCSegmentation(voc).load(0)
    assert tuple(sample["image"].shape) == (3, 24, 32)
    assert tuple(sample["label"].shape) == (24, 32)
    assert np.abs(sample["image"].permute(1, 2, 0).numpy().astype(int) - stored).mean() < 8

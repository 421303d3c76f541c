"""The shared session fixtures return complete folders in the documented layouts."""

from __future__ import annotations

from uss_slam.core.tum_io import CameraIntrinsics, read_file_list, read_trajectory


def test_sequence_fixture_layout(synthetic_sequence) -> None:
    root = synthetic_sequence(frames=4, size=(64, 48))
    assert root is synthetic_sequence(frames=4, size=(64, 48))  # cached for the session
    rgb = read_file_list(root / "rgb.txt")
    depth = read_file_list(root / "depth.txt")
    assert len(rgb) == len(depth) == 4
    assert sorted(p.name for p in (root / "labels").iterdir()) == sorted(
        f.split("/")[1] for f in rgb.files
    )
    assert len(read_trajectory(root / "groundtruth.txt")) > 4
    cam = CameraIntrinsics.from_yaml(root / "intrinsics.yaml")
    assert (cam.width, cam.height) == (64, 48)


def test_voc_fixture_layout(synthetic_voc) -> None:
    root = synthetic_voc(images=5, size=(64, 48))
    assert root.name == "VOC2012" and root.parent.name == "VOCdevkit"
    train = (root / "ImageSets" / "Segmentation" / "train.txt").read_text().split()
    val = (root / "ImageSets" / "Segmentation" / "val.txt").read_text().split()
    assert len(train) == 4 and len(val) == 1
    for name in train + val:
        assert (root / "JPEGImages" / f"{name}.jpg").is_file()
        assert (root / "SegmentationClass" / f"{name}.png").is_file()

"""TUM sequence reader: round trip, association, camera resolution, prefetching, bad inputs."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.tum_io import TUM_CAMERAS, read_file_list, resolve_camera, write_file_list
from uss_slam.slam_eval.sequence import MIN_STRIDED_FRAMES, TumSequence


def test_round_trip_values_and_order(write_sequence) -> None:
    root = write_sequence(n=5)
    seq = TumSequence(root, load_labels=True)
    assert len(seq) == 5 and seq.unmatched_rgb == 0
    assert seq.image_size == (32, 24)
    listed = read_file_list(root / "rgb.txt")
    np.testing.assert_array_equal(seq.stamps, listed.stamps)
    for i, frame in enumerate(seq.frames(prefetch=2)):
        assert frame.index == i
        assert frame.rgb.shape == (24, 32, 3) and frame.rgb.dtype == np.uint8
        assert tuple(frame.rgb[0, 0]) == (i, 2 * i, 3 * i)  # RGB order, not BGR
        assert frame.gray.shape == (24, 32)
        assert frame.depth.dtype == np.float32
        np.testing.assert_allclose(frame.depth, (1000 + i) / 5000.0, rtol=1e-6)
        np.testing.assert_array_equal(frame.labels, i % 4)
    assert seq.groundtruth is not None and len(seq.groundtruth) > 10


def test_prefetch_yields_the_same_frames_as_direct_loading(write_sequence) -> None:
    seq = TumSequence(write_sequence(n=7))
    direct = [seq.load(i) for i in range(len(seq))]
    for prefetch, workers in ((0, 1), (1, 1), (3, 1), (20, 1), (3, 2), (5, 3)):
        frames = list(seq.frames(prefetch=prefetch, workers=workers))
        assert [f.index for f in frames] == list(range(7))
        for a, b in zip(direct, frames, strict=True):
            np.testing.assert_array_equal(a.rgb, b.rgb)
            np.testing.assert_array_equal(a.depth, b.depth)
            assert b.labels is None  # labels not requested
    # prepare() runs in the workers; results keep frame order.
    sizes = list(seq.prepared(lambda f: (f.index, f.gray.shape), prefetch=4, workers=2))
    assert sizes == [(i, (24, 32)) for i in range(7)]


def test_association_with_offsets_counts_unmatched(write_sequence) -> None:
    root = write_sequence(n=6, depth_offset=0.012)
    rgb = read_file_list(root / "rgb.txt")
    depth = read_file_list(root / "depth.txt")
    seq = TumSequence(root)
    assert len(seq) == 6 and seq.unmatched_rgb == 0
    np.testing.assert_allclose([r.depth_stamp - r.stamp for r in seq.records], 0.012, atol=1e-6)
    # Depth 12 ms late is out of reach of a 10 ms window: nothing associates.
    with pytest.raises(DataFormatError, match=r"no depth stamp within 0\.01 s"):
        TumSequence(root, max_diff=0.01)
    # Drop two depth frames: their colour frames have no partner (the neighbours are 33 ms off).
    keep = [0, 2, 3, 5]
    write_file_list(
        root / "depth.txt", depth.stamps[keep], [depth.files[k] for k in keep], "depth maps"
    )
    seq = TumSequence(root)
    assert len(seq) == 4 and seq.unmatched_rgb == 2
    np.testing.assert_array_equal(seq.stamps, rgb.stamps[keep])
    assert [r.depth_path.name for r in seq.records] == [Path(depth.files[k]).name for k in keep]


def test_start_stride_max_frames(write_sequence) -> None:
    seq = TumSequence(write_sequence(n=30), start=1, stride=3, max_frames=2)
    all_stamps = TumSequence(seq.path).stamps
    np.testing.assert_array_equal(seq.stamps, all_stamps[[1, 4]])
    assert [r.index for r in seq.records] == [0, 1]


def test_camera_resolution(write_sequence) -> None:
    root = write_sequence(size=(64, 48))
    own = TumSequence(root)
    assert own.camera == TUM_CAMERAS["fr3"].scaled(64, 48)
    assert own.camera_source.endswith("intrinsics.yaml")
    fr1 = TumSequence(root, camera="fr1")
    assert fr1.camera == TUM_CAMERAS["fr1"].scaled(64, 48) and fr1.camera.has_distortion
    (root / "intrinsics.yaml").unlink()
    assert TumSequence(root).camera == TUM_CAMERAS["fr3"].scaled(64, 48)
    cam, source = resolve_camera("FR2", root, (640, 480))
    assert cam == TUM_CAMERAS["fr2"] and source == "fr2"


def test_camera_from_path_must_match_image_size(write_sequence, tmp_path: Path) -> None:
    root = write_sequence(size=(32, 24))
    good = tmp_path / "cam.yaml"
    TUM_CAMERAS["fr3"].scaled(32, 24).to_yaml(good)
    assert TumSequence(root, camera=str(good)).camera_source == str(good)
    wrong = tmp_path / "wrong.yaml"
    TUM_CAMERAS["fr3"].to_yaml(wrong)
    with pytest.raises(DataFormatError, match=r"wrong\.yaml: camera is 640x480 but .* 32x24"):
        TumSequence(root, camera=str(wrong))


# ---------------------------------------------------------------------------- bad inputs


def test_not_a_folder(tmp_path: Path) -> None:
    with pytest.raises(
        DataFormatError, match=r"nope: does not exist; expected a TUM sequence folder"
    ):
        TumSequence(tmp_path / "nope")


def test_missing_rgb_list(write_sequence) -> None:
    root = write_sequence()
    (root / "rgb.txt").unlink()
    with pytest.raises(DataFormatError, match=r"rgb\.txt: not a TUM RGB-D sequence"):
        TumSequence(root)


def test_unparsable_line_names_file_and_line(write_sequence) -> None:
    root = write_sequence()
    lines = (root / "depth.txt").read_text().splitlines()
    lines[4] = "12x.5 depth/a.png"
    (root / "depth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r"depth\.txt:5: expected a number"):
        TumSequence(root)


def test_missing_image_file_names_it(write_sequence) -> None:
    root = write_sequence()
    victim = sorted((root / "depth").iterdir())[2]
    victim.unlink()
    with pytest.raises(DataFormatError) as info:
        TumSequence(root)
    # The list file and line that name the image (the third depth entry, after 3 comment lines).
    assert str(info.value) == f"{root / 'depth.txt'}:6: listed image depth/{victim.name} not found"


def test_unreadable_image(write_sequence) -> None:
    root = write_sequence()
    victim = sorted((root / "rgb").iterdir())[0]
    victim.write_bytes(b"not a png")
    with pytest.raises(DataFormatError, match=r"not a readable image"):
        TumSequence(root)


def test_depth_size_mismatch_names_depth_file(write_sequence) -> None:
    root = write_sequence(n=4)
    victim = sorted((root / "depth").iterdir())[3]
    cv2.imwrite(str(victim), np.zeros((12, 16), np.uint16))
    seq = TumSequence(root)  # first frame is fine; the fourth fails when loaded
    with pytest.raises(DataFormatError) as info:
        list(seq.frames(prefetch=2))
    assert victim.name in str(info.value)
    assert "depth image is 16x12 but the colour image" in str(info.value)


def test_a_colour_frame_of_another_size_is_named_not_its_depth(write_sequence) -> None:
    root = write_sequence(n=4)
    victim = sorted((root / "rgb").iterdir())[2]
    cv2.imwrite(str(victim), np.zeros((12, 16, 3), np.uint8))
    seq = TumSequence(root)
    with pytest.raises(DataFormatError) as info:
        list(seq.frames(prefetch=2))
    assert str(info.value) == f"{victim}: image is 16x12 but the sequence's first frame is 32x24"


def test_depth_must_be_uint16(write_sequence) -> None:
    root = write_sequence(n=2)
    victim = sorted((root / "depth").iterdir())[0]
    cv2.imwrite(str(victim), np.zeros((24, 32), np.uint8))
    with pytest.raises(DataFormatError, match=r"expected a single-channel uint16 depth PNG"):
        TumSequence(root)


def test_unknown_camera_name(write_sequence) -> None:
    with pytest.raises(UssSlamError, match=r"sequence\.camera='fr9': not one of fr1, fr2, fr3"):
        TumSequence(write_sequence(), camera="fr9")


def test_bad_intrinsics_file(write_sequence, tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("fx: 1\nfy: [oops\n")
    with pytest.raises(DataFormatError, match=r"bad\.yaml:3: not valid YAML \(expected ','"):
        TumSequence(write_sequence(), camera=str(bad))
    incomplete = tmp_path / "incomplete.yaml"
    incomplete.write_text("fx: 500\nfy: 500\n")
    with pytest.raises(DataFormatError, match=r"^sequence\.camera=.*incomplete\.yaml: expected "
                                              r"a mapping with keys"):  # fmt: skip
        TumSequence(write_sequence(name="other"), camera=str(incomplete))


def test_bad_own_intrinsics_file(write_sequence) -> None:
    root = write_sequence()
    (root / "intrinsics.yaml").write_text("fx: -3\nfy: 1\ncx: 0\ncy: 0\nwidth: 32\nheight: 24\n")
    with pytest.raises(DataFormatError, match=r"intrinsics\.yaml: fx must be > 0, got -3"):
        TumSequence(root)


def test_labels_requested_but_missing(write_sequence) -> None:
    root = write_sequence()
    shutil.rmtree(root / "labels")
    assert len(TumSequence(root)) == 6  # fine without labels
    with pytest.raises(
        DataFormatError, match=r"labels: labels requested but the folder does not exist"
    ):
        TumSequence(root, load_labels=True)


def test_label_file_missing_or_wrong(write_sequence) -> None:
    root = write_sequence()
    labels = sorted((root / "labels").iterdir())
    labels[1].unlink()
    with pytest.raises(DataFormatError, match=re_escape(str(labels[1])) + ": label of rgb/"):
        TumSequence(root, load_labels=True)
    root2 = write_sequence(name="rgb_labels")
    first = sorted((root2 / "labels").iterdir())[0]
    cv2.imwrite(str(first), np.zeros((24, 32, 3), np.uint8))
    with pytest.raises(DataFormatError, match=r"expected a single-channel uint8 class-id PNG"):
        TumSequence(root2, load_labels=True)


def test_no_association_at_all(write_sequence) -> None:
    root = write_sequence(depth_offset=0.5)
    with pytest.raises(DataFormatError, match=r"depth\.txt: no depth stamp within 0\.02 s"):
        TumSequence(root)


def test_bad_selection_arguments(write_sequence) -> None:
    root = write_sequence()
    with pytest.raises(UssSlamError, match="stride >= 1"):
        TumSequence(root, stride=0)
    with pytest.raises(
        UssSlamError, match=r"sequence.start=10: past the 6 associated frames of .*; expected 0..5"
    ):
        TumSequence(root, start=10)


def re_escape(text: str) -> str:
    import re

    return re.escape(text)


def test_a_stride_that_leaves_fewer_than_ten_frames_names_the_key(write_sequence) -> None:
    root = write_sequence(n=28)
    floor = {"min_strided_frames": MIN_STRIDED_FRAMES}  # as the SLAM runs open it
    assert len(TumSequence(root, stride=3, **floor)) == 10  # frames 0, 3, ..., 27
    with pytest.raises(UssSlamError) as info:
        TumSequence(root, stride=4, **floor)
    message = str(info.value)
    assert message.startswith("sequence.stride=4: leaves 7 of the 28 associated frames of ")
    assert message.endswith("expected at least 10 (a stride of at most 3)")
    with pytest.raises(UssSlamError, match=r"leaves 9 of the 27 associated frames"):
        TumSequence(root, start=1, stride=3, **floor)
    # Scoring masks on every n-th frame has no floor.
    assert len(TumSequence(root, stride=4)) == 7
    assert len(TumSequence(write_sequence(n=6, name="short"))) == 6  # stride 1: the user's frames

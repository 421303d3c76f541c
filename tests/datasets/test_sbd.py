"""SBD (benchmark_RELEASE) on a fixture of MATLAB ``GTcls`` structs written with scipy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io
import torch
from realdata_helpers import paint_voc, standard_scenes, write_gtcls, write_sbd, write_voc

from uss_slam.core.classes import voc_lut
from uss_slam.core.errors import DataFormatError
from uss_slam.datasets.sbd import SBDSegmentation, read_gtcls_segmentation
from uss_slam.datasets.voc import VOCSegmentation

torch.set_num_threads(1)
SHAPE = (40, 48)


def _labels() -> dict[str, np.ndarray]:
    return {name: paint_voc(SHAPE, scene) for name, scene in standard_scenes(SHAPE).items()}


@pytest.fixture
def sbd(tmp_path: Path) -> Path:
    names = list(_labels())
    return write_sbd(tmp_path, _labels(), {"train": names[:4], "val": names[4:]})


def test_gtcls_struct_is_read_as_matlab_writes_it(sbd: Path) -> None:
    mat = scipy.io.loadmat(sbd / "cls" / "2008_000001.mat")
    assert mat["GTcls"].dtype.names == ("Boundaries", "Segmentation", "CategoriesPresent")
    np.testing.assert_array_equal(
        read_gtcls_segmentation(sbd / "cls" / "2008_000001.mat"), _labels()["2008_000001"]
    )


def test_roots_splits_and_remapped_classes(sbd: Path) -> None:
    labels = _labels()
    for root in (sbd, sbd.parent, sbd.parent.parent):  # dataset/, benchmark_RELEASE/, its parent
        dataset = SBDSegmentation(root, split="train")
        assert dataset.root == sbd and len(dataset) == 4
    assert [item.name for item in SBDSegmentation(sbd, split="val").items] == ["2008_000005"]
    dataset = SBDSegmentation(sbd, split="train")
    for index, item in enumerate(dataset.items):
        assert item.image == sbd / "img" / f"{item.name}.jpg"
        assert item.label == sbd / "cls" / f"{item.name}.mat"
        np.testing.assert_array_equal(dataset.read_label(index), voc_lut()[labels[item.name]])
    sample = dataset[0]
    assert sample["label"].dtype == torch.int64 and sample["label"].shape == SHAPE
    assert set(torch.unique(sample["label"]).tolist()) == {0, 1, 2, 3, 255}


def test_sbd_and_voc_give_the_same_labels(sbd: Path, tmp_path: Path) -> None:
    voc = write_voc(tmp_path / "voc", _labels(), {"train": list(_labels())[:4]})
    from_voc, from_sbd = VOCSegmentation(voc), SBDSegmentation(sbd)
    for index in range(4):
        assert from_voc.items[index].name == from_sbd.items[index].name
        np.testing.assert_array_equal(from_voc.read_label(index), from_sbd.read_label(index))


def test_missing_roots_lists_and_files(sbd: Path, tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match=r"nowhere: SBD root not found"):
        SBDSegmentation(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match=r"empty: not an SBD tree: expected img/ and cls/"):
        SBDSegmentation(tmp_path / "empty")
    with pytest.raises(DataFormatError, match=r"train_noval\.txt: .* not found \(train_noval"):
        SBDSegmentation(sbd, split="train_noval")
    with pytest.raises(DataFormatError) as info:
        SBDSegmentation(sbd, split="test")
    assert str(info.value).endswith("test.txt: split list for split 'test' not found")
    (sbd / "cls" / "2008_000003.mat").unlink()
    with pytest.raises(
        DataFormatError, match=r"train\.txt:3: .*2008_000003\.mat .*the image 2008_000003\.jpg has"
    ):
        SBDSegmentation(sbd)
    skipping = SBDSegmentation(sbd, on_error="skip")
    assert len(skipping) == 3 and [e.line for e in skipping.skipped] == [3]


def test_bad_mat_files_name_the_file(sbd: Path) -> None:
    dataset = SBDSegmentation(sbd)
    path = sbd / "cls" / "2008_000002.mat"
    path.write_bytes(b"MATLAB 5.0 MAT-file, truncated")
    with pytest.raises(DataFormatError, match=r"2008_000002\.mat: cannot read MAT file"):
        dataset.read_label(1)
    scipy.io.savemat(path, {"GTinst": {"Segmentation": np.zeros(SHAPE, np.uint8)}})
    with pytest.raises(DataFormatError, match=r"2008_000002\.mat: no GTcls variable"):
        dataset.read_label(1)
    scipy.io.savemat(path, {"GTcls": {"Boundaries": np.zeros((20, 1))}})
    with pytest.raises(DataFormatError, match=r"2008_000002\.mat: GTcls must be a struct with"):
        dataset.read_label(1)
    scipy.io.savemat(path, {"GTcls": {"Segmentation": np.zeros(SHAPE, np.float64) + 0.5}})
    with pytest.raises(DataFormatError, match=r"must be a 2-D integer array"):
        dataset.read_label(1)
    bad = _labels()["2008_000002"].copy()
    bad[0, 0] = 42  # no VOC index
    write_gtcls(path, bad)
    with pytest.raises(DataFormatError, match=r"2008_000002\.mat: label values \[42\]"):
        dataset.read_label(1)
    write_gtcls(path, np.zeros((10, 10), np.uint8))
    with pytest.raises(DataFormatError, match=r"2008_000002\.mat: label is 10×10 but its image"):
        dataset[1]

"""Source selection over VOC / SBD / COCO fixtures: class filter, overlap, caps, manifest."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from realdata_helpers import paint_voc, standard_scenes, write_coco, write_sbd, write_voc

from uss_slam.core.classes import voc_lut
from uss_slam.core.errors import DataFormatError
from uss_slam.datasets.base import SegmentationDataset
from uss_slam.datasets.coco import COCOSegmentation
from uss_slam.datasets.datamodule import UDADataModule
from uss_slam.datasets.sbd import SBDSegmentation
from uss_slam.datasets.selection import MANIFEST_NAME, SelectedSources, Selection, SelectionError
from uss_slam.datasets.voc import VOCSegmentation

torch.set_num_threads(1)
pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")
SHAPE = (40, 48)
NAMES = list(standard_scenes(SHAPE))  # 2008_000001 .. 2008_000005


def _labels() -> dict[str, np.ndarray]:
    """Project-class labels of the five standard scenes."""
    return {n: voc_lut()[paint_voc(SHAPE, s)] for n, s in standard_scenes(SHAPE).items()}


@pytest.fixture
def roots(tmp_path: Path) -> dict[str, Path]:
    voc_labels = {n: paint_voc(SHAPE, s) for n, s in standard_scenes(SHAPE).items()}
    scenes = {k + 1: (f"{n}.jpg", s) for k, (n, s) in enumerate(standard_scenes(SHAPE).items())}
    return {
        "voc": write_voc(
            tmp_path / "voc",
            voc_labels,
            {"trainval": NAMES, "train": NAMES[:3], "val": NAMES[3:]},
        ),
        "sbd": write_sbd(tmp_path / "sbd", voc_labels, {"train": NAMES}),
        "coco": write_coco(tmp_path / "coco", scenes, SHAPE),
        "cache": tmp_path / "cache",
    }


def _select(roots: dict[str, Path], sets: str = "voc", **selection) -> SelectedSources:  # noqa: ANN003
    make = {
        "voc": lambda: VOCSegmentation(roots["voc"], split=selection.pop("voc_split", "trainval")),
        "sbd": lambda: SBDSegmentation(roots["sbd"]),
        "coco": lambda: COCOSegmentation(roots["coco"], cache_dir=roots["cache"]),
    }
    on_error = selection.pop("on_error", "raise")
    chosen = {name: make[name]() for name in sets.split(",")}
    return SelectedSources(
        selection=Selection(**selection), on_error=on_error, cache_dir=roots["cache"], **chosen
    )


def _ids(selected: SelectedSources, name: str) -> list[str]:
    return [selected.sets[name].items[i].name for i in selected.chosen[name]]


@pytest.mark.parametrize(
    ("classes", "require", "min_pixels"),
    [
        (["person", "chair", "monitor"], "any", 1),
        (["person", "chair", "monitor"], "all", 1),
        (["monitor"], "any", 1),
        (["person", "monitor"], "all", 1),
        (["person"], "any", 100),
        (["person", "chair"], "any", {"person": 100, "chair": 200}),
        ([], "any", 1),
    ],
)
def test_class_filter_any_all_and_min_pixels(
    roots: dict[str, Path], classes: list[str], require: str, min_pixels: int | dict
) -> None:
    from uss_slam.core.classes import CLASS_NAMES

    def shows(label: np.ndarray, name: str) -> bool:
        need = min_pixels if isinstance(min_pixels, int) else min_pixels.get(name, 1)
        return int((label == CLASS_NAMES.index(name)).sum()) >= max(need, 1)

    expected = [
        name
        for name, label in _labels().items()
        if not classes or (all if require == "all" else any)(shows(label, c) for c in classes)
    ]
    assert expected  # every case keeps some images
    for sets in ("voc", "coco"):  # the same objects: VOC and COCO select the same images
        selected = _select(roots, sets, classes=classes, require=require, min_pixels=min_pixels)
        chosen = _ids(selected, sets)
        if sets == "coco":
            chosen = [NAMES[int(i) - 1] for i in chosen]
        assert chosen == expected
        summary = selected.summary[sets]
        assert summary.listed == 5 and summary.selected == len(expected)
        assert summary.classes == 5 - len(expected)


def test_caps_are_seeded_subsets_and_counted(roots: dict[str, Path]) -> None:
    full = _ids(_select(roots, "voc"), "voc")
    assert full == NAMES[:4]
    capped = [_ids(_select(roots, "voc", max_images={"voc": 2}, seed=s), "voc") for s in range(6)]
    assert all(len(c) == 2 and set(c) <= set(full) and c == sorted(c) for c in capped)
    assert capped[0] == _ids(_select(roots, "voc", max_images={"voc": 2}, seed=0), "voc")
    assert len({tuple(c) for c in capped}) > 1  # the seed picks the subset
    selected = _select(roots, "voc", max_images={"voc": 3})
    assert selected.summary["voc"].cap == 1 and len(selected) == 3
    assert len(_select(roots, "voc", max_images={"voc": None})) == 4
    with pytest.raises(SelectionError, match=r"max_images names \['coco'\], which are not"):
        _select(roots, "voc", max_images={"coco": 2})


def test_samples_concatenate_the_sets(
    roots: dict[str, Path], caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level("INFO", logger="uss_slam.datasets.selection"):
        selected = _select(roots, "voc,coco", voc_split="train")
    assert "source selection (require any of person, chair, monitor (min_pixels 1))" in caplog.text
    assert selected.summary_table() in caplog.text
    assert [selected[i]["name"] for i in range(len(selected))] == [
        "voc/2008_000001", "voc/2008_000002", "voc/2008_000003",
        "coco/1", "coco/2", "coco/3", "coco/4",
    ]  # fmt: skip
    labels = _labels()
    assert torch.equal(selected[4]["label"], torch.from_numpy(labels[NAMES[1]]).long())
    assert "total" in selected.summary_table()


def test_sbd_images_in_voc_val_or_in_the_voc_set_are_removed(roots: dict[str, Path]) -> None:
    # VOC train = ids 1..3, VOC val = ids 4..5, SBD train = ids 1..5.
    selected = _select(roots, "voc,sbd", voc_split="train", classes=[])
    assert _ids(selected, "sbd") == [] and selected.summary["sbd"].overlap == 5
    only_val = _select(roots, "voc,sbd", voc_split="train", classes=[], drop_duplicates=False)
    assert _ids(only_val, "sbd") == NAMES[:3]  # ids 4, 5 are in VOC val
    only_dupes = _select(roots, "voc,sbd", voc_split="train", classes=[], exclude_voc_val=False)
    assert _ids(only_dupes, "sbd") == NAMES[3:]  # ids 1..3 are VOC's own (VOC's label wins)
    val_list = roots["voc"] / "ImageSets" / "Segmentation" / "val.txt"
    alone = _select(roots, "sbd", classes=[], voc_val_list=str(val_list))
    assert _ids(alone, "sbd") == NAMES[:3] and alone.summary["sbd"].overlap == 2
    with pytest.raises(SelectionError, match="exclude_voc_val: set 'sbd' is SBD but no VOC set"):
        _select(roots, "sbd")
    assert len(_select(roots, "sbd", classes=[], exclude_voc_val=False)) == 5


def test_manifest_is_written_and_replays_the_selection(
    roots: dict[str, Path], tmp_path: Path
) -> None:
    selected = _select(roots, "voc,coco", voc_split="train", max_images={"coco": 2}, seed=3)
    path = selected.write_manifest(tmp_path / "run")
    assert path == tmp_path / "run" / MANIFEST_NAME
    manifest = json.loads(path.read_text())
    assert manifest["sets"]["voc"]["ids"] == _ids(selected, "voc")
    assert manifest["sets"]["coco"]["ids"] == _ids(selected, "coco")
    assert manifest["sets"]["voc"]["split"] == "train"
    assert manifest["sets"]["coco"]["split"] == "train"
    assert manifest["summary"]["coco"]["cap"] == 2 and manifest["selection"]["seed"] == 3
    # Replaying: exactly those ids, whatever the class filter and caps say now.
    replay = _select(roots, "voc,coco", voc_split="train", require="all", manifest=str(path))
    assert replay.index == selected.index
    assert replay.summary["voc"].manifest == 0 and replay.summary["coco"].manifest == 3
    manifest["sets"]["voc"]["ids"].append("2009_999999")
    path.write_text(json.dumps(manifest))
    with pytest.raises(DataFormatError, match=r"source_manifest\.json: set 'voc': 1 id\(s\) are"):
        _select(roots, "voc,coco", voc_split="train", manifest=str(path))
    with pytest.raises(DataFormatError, match=r"the manifest's sets \['coco', 'voc'\] differ"):
        _select(roots, "voc", manifest=str(path))
    path.write_text("{")
    with pytest.raises(DataFormatError, match=r"source_manifest\.json:1: not valid JSON"):
        _select(roots, "voc", manifest=str(path))


def test_the_data_module_writes_the_manifest_into_the_run_directory(
    roots: dict[str, Path], tmp_path: Path
) -> None:
    selected = _select(roots, "voc")
    module = UDADataModule(selected, selected, manifest_dir=tmp_path / "run")
    module.setup("fit")
    assert module.manifest_path == tmp_path / "run" / MANIFEST_NAME
    assert json.loads(module.manifest_path.read_text())["sets"]["voc"]["ids"] == NAMES[:4]


@pytest.mark.parametrize(
    ("settings", "culprit"),
    [
        ({"classes": ["person", "chair", "monitor"], "require": "all", "min_pixels": 400},
         r"the class filter \(require all of person, chair, monitor \(min_pixels 400\)\) removed"),
        ({"max_images": {"voc": 0}}, r"the max_images cap removed the last ones"),
        ({"voc_split": "val", "classes": ["chair"]}, r"the class filter .* removed the last ones"),
    ],
)  # fmt: skip
def test_an_empty_selection_names_the_filter(
    roots: dict[str, Path], settings: dict, culprit: str
) -> None:
    with pytest.raises(SelectionError, match=r"the source selection left no images: " + culprit):
        _select(roots, "voc", **settings)


def test_an_empty_selection_by_overlap_and_bad_input(roots: dict[str, Path]) -> None:
    with pytest.raises(SelectionError, match=r"the overlap rule \(SBD vs VOC\) removed the last"):
        everything = roots["voc"] / "ImageSets" / "Segmentation" / "trainval.txt"
        _select(roots, "sbd", classes=[], voc_val_list=str(everything))
    for name in NAMES:
        (roots["voc"] / "SegmentationClass" / f"{name}.png").write_bytes(b"broken")
    with pytest.raises(SelectionError, match=r"bad input \(on_error=skip\) removed the last ones"):
        _select(roots, "voc", on_error="skip")


def _break(roots: dict[str, Path]) -> dict[str, str]:
    """Four kinds of bad files in the VOC fixture; returns name -> expected message."""
    voc = roots["voc"]
    jpeg = voc / "JPEGImages" / "2008_000001.jpg"
    jpeg.write_bytes(jpeg.read_bytes()[:-100])
    png = voc / "SegmentationClass" / "2008_000002.png"
    png.write_bytes(png.read_bytes()[:-20])
    bad = paint_voc(SHAPE, standard_scenes(SHAPE)["2008_000003"])
    bad[0, 0] = 77
    write_voc(voc.parent.parent, {"2008_000003": bad}, {})
    write_voc(voc.parent.parent, {"2008_000004": np.zeros((20, 20), np.uint8)}, {})
    (voc / "SegmentationClass" / "2008_000004.png").write_bytes(
        (voc / "SegmentationClass" / "2008_000005.png").read_bytes()
    )
    return {
        "2008_000001": r"2008_000001\.jpg: truncated JPEG",
        "2008_000002": r"2008_000002\.png: truncated PNG: .*\(no IEND chunk\)",
        "2008_000003": r"2008_000003\.png: label values \[77\]",
        "2008_000004": r"2008_000004\.png: label is 48×40 but its image 2008_000004\.jpg is 20×20",
    }


def test_bad_files_raise_or_are_skipped_counted_and_reported(
    roots: dict[str, Path], tmp_path: Path
) -> None:
    expected = _break(roots)
    with pytest.raises(DataFormatError, match=expected["2008_000001"]):
        _select(roots, "voc", classes=[])
    selected = _select(roots, "voc", classes=[], on_error="skip")
    assert _ids(selected, "voc") == ["2008_000005"]
    assert selected.summary["voc"].bad_input == 4
    messages = json.loads(selected.write_manifest(tmp_path).read_text())["skipped"]["voc"]
    assert len(messages) == 4
    for message, pattern in zip(messages, expected.values(), strict=True):
        assert re.search(pattern, message), message


def test_label_statistics_are_cached_until_a_label_changes(
    roots: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    first = _select(roots, "voc")
    calls: list[int] = []
    original = SegmentationDataset.label_stats

    def counting(self: SegmentationDataset, index: int):  # noqa: ANN202
        calls.append(index)
        return original(self, index)

    monkeypatch.setattr(SegmentationDataset, "label_stats", counting)
    again = _select(roots, "voc")
    assert calls == [] and again.index == first.index
    assert again.summary["voc"].pixels == first.summary["voc"].pixels
    # 2008_000005 (a dog) gets a monitor: only its statistics are read again.
    label = paint_voc(SHAPE, standard_scenes(SHAPE)["2008_000005"])
    label[:5, :5] = 20
    write_voc(roots["voc"].parent.parent, {"2008_000005": label}, {})
    changed = _select(roots, "voc")
    assert calls == [4] and _ids(changed, "voc") == NAMES


def test_invalid_settings() -> None:
    with pytest.raises(SelectionError, match="'table' is not a project class"):
        Selection(classes=["table"])
    with pytest.raises(SelectionError, match="require must be 'any' or 'all'"):
        Selection(require="most")  # type: ignore[arg-type]
    with pytest.raises(SelectionError, match="must not be negative"):
        Selection(min_pixels=-1)
    with pytest.raises(SelectionError, match="no source set configured"):
        SelectedSources()

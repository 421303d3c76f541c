"""COCO-format instances (COCO 2017 and annotation-tool exports) rasterised to project labels."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from realdata_helpers import (
    COCO_CATEGORIES,
    coco_json,
    ellipse,
    paint_voc,
    rect,
    save_jpeg,
    scene_image,
    standard_scenes,
    write_coco,
    write_voc,
)

from uss_slam.core.classes import COCO_TO_PROJECT, IGNORE_INDEX, voc_lut
from uss_slam.core.errors import DataFormatError
from uss_slam.datasets.coco import (
    DEFAULT_CATEGORIES,
    COCOSegmentation,
    category_table,
    normalize_name,
)
from uss_slam.datasets.voc import VOCSegmentation

torch.set_num_threads(1)
# pycocotools' decode under NumPy 2 (its own code, harmless).
pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")
SHAPE = (40, 48)


def _scenes() -> dict[int, tuple[str, list]]:
    return {
        k + 1: (f"{name}.jpg", scene)
        for k, (name, scene) in enumerate(standard_scenes(SHAPE).items())
    }


@pytest.fixture
def coco(tmp_path: Path) -> Path:
    return write_coco(tmp_path / "coco", _scenes(), SHAPE)


def _annotations(root: Path) -> Path:
    return root / "annotations" / "instances_train2017.json"


def _edit(root: Path, change) -> None:  # noqa: ANN001 - a function of the loaded JSON
    path = _annotations(root)
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def test_polygons_rle_uncompressed_rle_and_crowd(coco: Path) -> None:
    dataset = COCOSegmentation(coco)
    assert [item.name for item in dataset.items] == ["1", "2", "3", "4", "5"]
    assert all(
        item.image == coco / "train2017" / f"{name}.jpg"
        for item, (name, _) in zip(dataset.items, standard_scenes(SHAPE).items(), strict=True)
    )
    for index, scene in enumerate(standard_scenes(SHAPE).values()):
        np.testing.assert_array_equal(dataset.read_label(index), voc_lut()[paint_voc(SHAPE, scene)])
    label = dataset.read_label(0)
    assert (label[0:8, 30:48] == IGNORE_INDEX).all()  # the crowd (uncompressed RLE) is ignored
    assert (label[5:30, 10:20] == 1).all()  # the smaller person wins over the monitor (polygon)
    assert label[3, 3] == 3 and label[30, 38] == 2  # monitor polygon, chair RLE
    assert dataset.read_label(4).max() == 0  # a dog only: background
    sample = dataset[0]
    assert sample["label"].dtype == torch.int64 and sample["image"].shape == (3, *SHAPE)
    assert [sorted(dataset.present_classes(i)) for i in range(5)] == [
        [1, 2, 3],
        [1],
        [2],
        [1, 3],
        [],
    ]


def test_same_objects_as_voc_and_as_coco_give_the_same_masks(coco: Path, tmp_path: Path) -> None:
    scenes = standard_scenes(SHAPE)
    labels = {name: paint_voc(SHAPE, scene) for name, scene in scenes.items()}
    voc = VOCSegmentation(write_voc(tmp_path / "voc", labels, {"train": list(labels)}))
    from_coco = COCOSegmentation(coco, cache_dir=tmp_path / "cache")
    for index in range(len(scenes)):
        np.testing.assert_array_equal(voc.read_label(index), from_coco.read_label(index))
        assert torch.equal(voc[index]["label"], from_coco[index]["label"])


def test_annotation_tool_export_maps_by_name(tmp_path: Path) -> None:
    """A CVAT / labelme style export: other category ids and names, sub-folder file names."""
    shape = (24, 32)
    scene = [
        rect(shape, 0, 0, 16, 24, 20),
        rect(shape, 4, 4, 10, 20, 15),
        ellipse(shape, 24, 12, 5, 5, 9),
    ]
    categories = [
        {"id": 1, "name": "tv/monitor"},
        {"id": 2, "name": "Person"},
        {"id": 3, "name": "office chair"},
        {"id": 4, "name": "cup"},
    ]
    data = coco_json(
        {7: ("rgb/1305031102.175304.png", scene)},
        shape,
        categories=categories,
        voc_to_coco={20: 1, 15: 2, 9: 3},
    )
    data["annotations"].append({**data["annotations"][0], "id": 99, "category_id": 4})  # a cup
    sequence = tmp_path / "walking_xyz"
    save_jpeg(sequence / "rgb" / "1305031102.175304.png", scene_image(shape, 0))
    export = tmp_path / "export" / "instances_default.json"
    export.parent.mkdir()
    export.write_text(json.dumps(data))
    categories_cfg = {"person": ["person"], "chair": ["office chair"], "monitor": ["tv/monitor"]}
    dataset = COCOSegmentation(annotations=export, images=sequence, categories=categories_cfg)
    assert dataset.items[0].image == sequence / "rgb" / "1305031102.175304.png"
    assert dataset.items[0].name == "7"
    expected = paint_voc(shape, scene)
    np.testing.assert_array_equal(dataset.read_label(0), voc_lut()[expected])
    # The default names accept 'tv/monitor' but not 'office chair': that chair is background.
    default = COCOSegmentation(annotations=export, images=sequence)
    np.testing.assert_array_equal(
        default.read_label(0), voc_lut()[np.where(expected == 9, 0, expected)]
    )
    assert normalize_name("TV / Monitor") == normalize_name("tvmonitor") == "tvmonitor"
    with pytest.raises(ValueError, match="'table' is not a project class"):
        COCOSegmentation(annotations=export, images=sequence, categories={"table": ["table"]})
    with pytest.raises(DataFormatError, match=r"instances_default\.json: no category matches"):
        COCOSegmentation(annotations=export, images=sequence, categories={"person": ["human"]})


def test_masks_are_cached_and_reused(coco: Path, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    cache = tmp_path / "cache"
    first = COCOSegmentation(coco, cache_dir=cache)
    first.prepare_labels(range(len(first)))
    folders = list((cache / "coco").iterdir())
    assert len(folders) == 1 and (folders[0] / "index.json").is_file()
    masks = sorted(p.name for p in (folders[0] / "masks").iterdir())
    assert masks == ["1.png", "2.png", "3.png", "4.png"]  # image 5 has no mapped annotation
    stamps = {p.name: p.stat().st_mtime_ns for p in (folders[0] / "masks").iterdir()}

    def no_parse(self):  # noqa: ANN001, ANN202
        raise AssertionError("the annotation JSON was parsed although the cache is current")

    monkeypatch.setattr(COCOSegmentation, "_parse", no_parse)
    again = COCOSegmentation(coco, cache_dir=cache)
    for index in range(len(again)):
        np.testing.assert_array_equal(again.read_label(index), first.read_label(index))
        assert again.label_stats(index).counts.tolist() == first.label_stats(index).counts.tolist()
    assert {p.name: p.stat().st_mtime_ns for p in (folders[0] / "masks").iterdir()} == stamps


def test_changed_annotations_or_mapping_invalidate_the_cache(coco: Path, tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    first = COCOSegmentation(coco, cache_dir=cache)
    first.prepare_labels(range(len(first)))
    assert (first.read_label(2) == 2).any()  # image 3: a chair

    def drop_image_3(data: dict) -> None:
        data["annotations"] = [a for a in data["annotations"] if a["image_id"] != 3]

    _edit(coco, drop_image_3)
    changed = COCOSegmentation(coco, cache_dir=cache)
    changed.prepare_labels(range(len(changed)))
    assert changed.read_label(2).max() == 0 and changed.present_classes(2) == frozenset()
    masks = sorted(p.name for p in (changed.cache / "masks").iterdir())  # type: ignore[operator]
    assert masks == ["1.png", "2.png", "4.png"]  # the stale mask of image 3 is gone
    shutil.rmtree(changed.cache / "masks")  # type: ignore[operator]
    fresh = COCOSegmentation(coco, cache_dir=cache)  # the index is current, its masks are gone
    np.testing.assert_array_equal(fresh.read_label(0), changed.read_label(0))
    assert (fresh.cache / "masks" / "1.png").is_file()  # type: ignore[operator]
    remapped = COCOSegmentation(coco, cache_dir=cache, categories={"person": ["person"]})
    assert remapped.read_label(0).max() == IGNORE_INDEX and set(
        np.unique(remapped.read_label(0))
    ) == {0, 1, 255}


def test_invalid_json_and_missing_keys_always_raise(coco: Path) -> None:
    path = _annotations(coco)
    path.write_text('{"images": [],\n "annotations": [\n oops]}')
    with pytest.raises(DataFormatError, match=r"instances_train2017\.json:3: not valid JSON"):
        COCOSegmentation(coco, on_error="skip")
    path.write_text(json.dumps({"images": [], "categories": []}))
    with pytest.raises(DataFormatError, match=r"missing required key\(s\) \['annotations'\]"):
        COCOSegmentation(coco, on_error="skip")
    path.write_text(json.dumps([1, 2]))
    with pytest.raises(DataFormatError, match="expected a JSON object"):
        COCOSegmentation(coco)
    path.write_text(json.dumps({"images": {}, "annotations": [], "categories": []}))
    with pytest.raises(DataFormatError, match="'images' must be a list"):
        COCOSegmentation(coco)
    path.unlink()
    with pytest.raises(DataFormatError, match=r"instances_train2017\.json: COCO annotation file"):
        COCOSegmentation(coco)
    with pytest.raises(DataFormatError, match=r"nowhere: COCO root not found"):
        COCOSegmentation(coco / "nowhere")


BAD_ENTRIES = {
    "image without size": (
        lambda d: d["images"][1].pop("width"),
        r"images\[1\]: missing required key\(s\) \['width'\]",
        {2},
    ),
    "annotation of an unknown image": (
        lambda d: d["annotations"][0].update(image_id=404),
        r"annotations\[0\] \(id 1\): image_id 404 is not in images",
        set(),
    ),
    "unknown category": (
        lambda d: d["annotations"][0].update(category_id=999),
        r"annotations\[0\] \(id 1\): category_id 999 is not in categories \(image 1, 2008_000001",
        {1},
    ),
    "odd polygon": (
        lambda d: d["annotations"][5].update(segmentation=[[1, 2, 3, 4, 5]]),
        r"annotations\[5\] \(id 6\): a polygon needs an even number >= 6 of coordinates, got 5 "
        r"\(image 2",
        {2},
    ),
    "RLE of another size": (
        lambda d: d["annotations"][2].update(segmentation={"size": [10, 10], "counts": "abc"}),
        r"annotations\[2\] \(id 3\): RLE size \[10, 10\] differs",
        {1},
    ),
    "uncompressed RLE of the wrong length": (
        lambda d: d["annotations"][0].update(segmentation={"size": [40, 48], "counts": [5, 5]}),
        r"annotations\[0\] \(id 1\): uncompressed RLE counts must be non-negative and sum to "
        r"1920 \(image 1, 2008_000001\.jpg\)",
        {1},
    ),
    "duplicate image id": (
        lambda d: d["images"].append({**d["images"][3], "file_name": "other.jpg"}),
        r"images\[5\]: duplicate image id 4",
        {4},
    ),
    "category without a name": (
        lambda d: d["categories"].append({"id": 5}),
        r"categories\[4\]: needs an integer 'id' and a 'name'",
        None,
    ),
    "annotation without segmentation": (
        lambda d: d["annotations"][4].pop("segmentation"),
        r"annotations\[4\] \(id 5\): missing required key\(s\) \['segmentation'\]",
        {2},
    ),
}


@pytest.mark.parametrize("case", list(BAD_ENTRIES))
def test_bad_entries_raise_or_are_skipped(coco: Path, case: str) -> None:
    change, message, dropped = BAD_ENTRIES[case]
    _edit(coco, change)
    with pytest.raises(DataFormatError, match=r"instances_train2017\.json: " + message):
        COCOSegmentation(coco)
    if dropped is None:  # the categories decide every label: always an error
        with pytest.raises(DataFormatError, match=message):
            COCOSegmentation(coco, on_error="skip")
        return
    skipping = COCOSegmentation(coco, on_error="skip")
    assert len(skipping.skipped) == 1 and "instances_train2017.json" in str(skipping.skipped[0])
    assert {int(item.name) for item in skipping.items} == {1, 2, 3, 4, 5} - dropped


def test_missing_or_mismatched_image_files(coco: Path, tmp_path: Path) -> None:
    (coco / "train2017" / "2008_000002.jpg").unlink()
    with pytest.raises(DataFormatError, match=r"image 2: file .*2008_000002\.jpg not found"):
        COCOSegmentation(coco)
    skipping = COCOSegmentation(coco, on_error="skip", cache_dir=tmp_path / "cache")
    assert [item.name for item in skipping.items] == ["1", "3", "4", "5"]
    assert len(skipping.skipped) == 1
    # A cache built with on_error=skip still holds the bad entries: raise reports them.
    _edit(coco, lambda d: d["images"][2].pop("height"))
    COCOSegmentation(coco, on_error="skip", cache_dir=tmp_path / "cache")
    with pytest.raises(DataFormatError, match=r"images\[2\]: missing required key"):
        COCOSegmentation(coco, cache_dir=tmp_path / "cache")
    save_jpeg(coco / "train2017" / "2008_000004.jpg", scene_image((20, 48), 0))
    with pytest.raises(
        DataFormatError, match=r"image 4 is 48×40 in the annotations but its file 2008_000004\.jpg"
    ):
        skipping.check_image(2, *SHAPE)


def test_undecodable_rle_fails_at_rasterisation_naming_the_image(
    coco: Path, tmp_path: Path
) -> None:
    from uss_slam.datasets.selection import SelectedSources, Selection

    def garble(data: dict) -> None:
        (rle,) = [a for a in data["annotations"] if a["id"] == 2]  # image 1's RLE chair
        rle["segmentation"]["counts"] = "\x7f\x7fzz!!"

    _edit(coco, garble)
    for cache in (None, tmp_path / "cache"):
        dataset = COCOSegmentation(coco, cache_dir=cache)
        with pytest.raises(DataFormatError, match=r"json: image 1: cannot rasterise"):
            SelectedSources(coco=dataset, selection=Selection(classes=[]))
        selected = SelectedSources(coco=dataset, selection=Selection(classes=[]), on_error="skip")
        assert [dataset.items[i].name for i in selected.chosen["coco"]] == ["2", "3", "4", "5"]
        assert selected.summary["coco"].bad_input == 1


def test_default_names_give_design_ids_on_the_official_categories() -> None:
    """The project's class map: COCO category ids 1 -> person, 62 -> chair, 72 (tv) -> monitor."""
    table = category_table(DEFAULT_CATEGORIES)
    mapped = {c["id"]: table.get(normalize_name(c["name"]), 0) for c in COCO_CATEGORIES}
    assert {k: v for k, v in mapped.items() if v} == COCO_TO_PROJECT

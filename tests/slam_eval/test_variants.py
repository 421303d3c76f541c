"""The variants table (``configs/variants.yaml``): its entries, and one line for a bad one."""

from __future__ import annotations

import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.variants import (
    Variant,
    check_filters,
    masks_orbslam3_input,
    read_table,
    variants,
)


def test_the_shipped_table_names_known_filters_and_its_orbslam3_variants() -> None:
    table = variants()
    assert list(table)[:3] == ["none", "geometry", "semantic"]
    assert table["oracle"] == Variant("oracle", "ground-truth masks", "labels", ("semantic",))
    assert table["semantic_crf"].crf and table["semantic_crf"].segmenter == "model"
    # ORB-SLAM3 takes the variants whose filters all find their pixels in the frame alone
    assert [n for n, v in table.items() if masks_orbslam3_input(v)] == [
        "none", "semantic", "semantic_crf", "oracle"
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("x: {label: X, segmenter: none, filters: [teleport]}",
         "v.yaml: variant x: unknown filter 'teleport'; choose from semantic, flow"),
        ("x: {label: X, segmenter: model, filters: semantic}",
         "v.yaml: variant x: filters: expected a list of filter names"),
        ("x: {label: X, segmenter: camera}",
         "v.yaml: variant x: segmenter 'camera'; expected one of none, labels, model"),
        ("x: {label: X, segmenter: none, crf: true}",
         "v.yaml: variant x: the dense CRF needs segmenter 'model'"),
        ("x: {label: X, segmenter: none, colour: red}",
         "v.yaml: variant x: unknown key 'colour'; expected label, segmenter, filters, crf"),
        ("x: {segmenter: none}", "v.yaml: variant x: expected a mapping with label, segmenter"),
        ("[a, b]", "v.yaml: expected a mapping of variant name -> entry"),
    ],
)  # fmt: skip
def test_a_bad_table_is_one_line(text: str, message: str) -> None:
    with pytest.raises(UssSlamError) as err:
        check_filters(read_table(text, "v.yaml"), ["semantic", "flow"], "v.yaml")
    assert str(err.value) == message or str(err.value).startswith(message)
    assert "\n" not in str(err.value)

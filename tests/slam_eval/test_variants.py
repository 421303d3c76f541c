"""The variants table (``configs/variants.yaml``): its entries, one line for a bad one, and
``uss-slam variant=<name>``."""

from __future__ import annotations

import pytest
from omegaconf import DictConfig
from shared_helpers import compose_slam_eval

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval import config as slam_config
from uss_slam.slam_eval.config import check
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


def _chosen(*overrides: str) -> DictConfig:
    """``uss-slam``'s config composed with ``overrides``, its variant chosen (the overrides as
    the command line's), checked."""
    cfg = compose_slam_eval(["sequence.path=/unused", "out_dir=/unused", *overrides])
    check(cfg, overrides)
    return cfg


def test_uss_slam_variant_sets_the_segmenter_filters_and_crf_as_the_table_says() -> None:
    oracle = _chosen("variant=oracle")
    assert oracle.segmenter._target_.endswith("LabelsSegmenter")
    assert list(oracle.filters) == ["semantic"]
    geometry = _chosen("variant=geometry", "filters=[geometry]", "segmenter=none")  # agreeing
    assert geometry.segmenter._target_.endswith("NoSegmenter")
    assert list(geometry.filters) == ["geometry"]
    crf = _chosen("variant=semantic_geometry_crf", "segmenter=onnx", "segmenter.path=m.onnx")
    assert crf.segmenter.crf is True and crf.segmenter.path == "m.onnx"
    assert list(crf.filters) == ["semantic", "geometry"]
    plain = _chosen("segmenter=labels", "filters=[semantic]")  # no variant: as before
    assert plain.variant is None and list(plain.filters) == ["semantic"]


@pytest.mark.parametrize(
    ("overrides", "line"),
    [
        (["variant=teleport"], "variant: expected one of 'none', 'geometry', 'semantic', "
         "'semantic_crf', 'semantic_geometry', 'semantic_geometry_crf', "
         "'semantic_geometry_object', 'oracle' or null, got 'teleport'"),
        (["variant=geometry", "filters=[flow]"], "filters=[flow]: variant=geometry runs "
         "filters=[geometry] (configs/variants.yaml); give one of them"),
        (["variant=geometry", "filters=[]"], "filters=[]: variant=geometry runs "
         "filters=[geometry] (configs/variants.yaml); give one of them"),
        (["variant=oracle", "segmenter=none"], "segmenter=none: variant=oracle segments with "
         "segmenter=labels (configs/variants.yaml); give one of them"),
        (["variant=semantic"], "variant=semantic: segments with an exported model: add "
         "segmenter=onnx segmenter.path=FILE.onnx"),
        (["variant=semantic", "segmenter=onnx", "segmenter.path=m.onnx", "segmenter.crf=true"],
         "segmenter.crf=true: variant=semantic runs without the dense CRF "
         "(configs/variants.yaml); give one of them"),
        (["variant=semantic_crf", "segmenter=onnx", "segmenter.path=m.onnx",
          "segmenter.crf=false"], "segmenter.crf=false: variant=semantic_crf runs with the "
         "dense CRF (configs/variants.yaml); give one of them"),
        (["variant=geometry", "compare=[[flow]]"],
         "compare: runs several filter sets, variant=geometry one; give one of them"),
    ],
)  # fmt: skip
def test_a_variant_that_cannot_be_run_as_given_is_one_line(overrides: list, line: str) -> None:
    with pytest.raises(UssSlamError) as err:
        _chosen(*overrides)
    assert str(err.value) == line


def test_uss_slam_stops_at_a_variant_naming_an_unknown_filter(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    table = {"teleport": Variant("teleport", "teleport", "none", ("teleport",))}
    monkeypatch.setattr(slam_config, "read_variants", lambda: table)
    with pytest.raises(UssSlamError) as err:
        _chosen()  # any run: the table is checked at startup
    assert str(err.value) == (
        "configs/variants.yaml: variant teleport: unknown filter 'teleport'; choose from "
        "semantic, flow, geometry, object (slam.filter_params)"
    )

"""uss-experiments and uss-demo take their SLAM variants from ``configs/variants.yaml``."""

from __future__ import annotations

import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines import demo
from uss_slam.pipelines.experiments import grid, tables
from uss_slam.slam_eval.variants import Variant, crf_pairs, model_free, read_table


def test_the_experiments_and_the_demo_read_the_variants_table() -> None:
    table = read_table()
    assert table == grid.VARIANTS
    assert {
        "harness": tuple(table),
        "orbslam3": ("none", "semantic", "semantic_crf", "oracle"),
    } == grid.SYSTEM_VARIANTS
    assert [(v.name, v.label, v.segmenter, v.filters, v.crf, v.model) for v in demo.VARIANTS] == [
        ("none", "no filter", "none", (), False, None),
        ("labels", "ground-truth masks", "labels", ("semantic",), False, None),
        ("source_only", "source-only", "model", ("semantic",), False, "source_only"),
        ("adabn", "AdaBN", "model", ("semantic",), False, "adabn"),
        ("adapted", "adapted", "model", ("semantic",), False, "adapted"),
        ("adapted_geometry", "adapted + geometry", "model", ("semantic", "geometry"), False,
         "adapted"),
    ]  # fmt: skip


def test_a_variant_naming_an_unknown_filter_stops_the_experiments_in_one_line(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    bad = {**grid.VARIANTS, "teleport": Variant("teleport", "teleport", "none", ("teleport",))}
    monkeypatch.setattr(grid, "VARIANTS", bad)
    with pytest.raises(UssSlamError) as err:
        grid.check_variant_filters()
    assert str(err.value).startswith(
        "configs/variants.yaml: variant teleport: unknown filter 'teleport'; choose from semantic"
    )


def test_the_tables_baselines_and_crf_pairs_come_from_the_variants_table() -> None:
    assert tables.BASELINES == ("none", "geometry", "oracle")
    assert tables.CRF_PAIRS == (("semantic", "semantic_crf"),
                                ("semantic_geometry", "semantic_geometry_crf"))  # fmt: skip
    # a new row reaches them without an edit here
    table = read_table(
        "flow: {label: flow, segmenter: none, filters: [flow]}\n"
        "semantic: {label: s, segmenter: model, filters: [semantic]}\n"
        "semantic_crf: {label: s+CRF, segmenter: model, filters: [semantic], crf: true}\n"
        "flow_crf: {label: f+CRF, segmenter: model, filters: [flow], crf: true}\n"
    )
    assert model_free(table) == ("flow",)
    assert crf_pairs(table) == (("semantic", "semantic_crf"),)  # flow_crf: no partner

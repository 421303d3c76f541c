"""The experiment grid of uss-experiments: trainings, segmentation evaluations and SLAM runs,
their ids and overrides, and the one-line errors for bad keys."""

from __future__ import annotations

from typing import Any

import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.core.schema import check
from uss_slam.pipelines.experiments.grid import (
    SYNTHETIC_SEQUENCES,
    TrainCell,
    expand,
    loss_combinations,
    training_cells,
)
from uss_slam.pipelines.experiments.schema import ExperimentsSchema
from uss_slam.train.method_configs import method_names

ALL_VARIANTS = [
    "none",
    "semantic",
    "geometry",
    "semantic_geometry",
    "semantic_geometry_object",
    "oracle",
]


def config(**changes: Any) -> dict[str, Any]:
    cfg: dict[str, Any] = {
        "grid": {
            "methods": ["source_only", "adaptsegnet"],
            "n_layers": [4, 5, 6, 7],
            "seeds": [0, 1, 2],
            "loss": {},
        },
        "sequences": ["walking_xyz", "walking_rpy", "walking_halfsphere", "static_xyz"],
        "variants": list(ALL_VARIANTS),
        "systems": ["harness"],
        "slam": {"every_model": False},
        "tables": {"n_layers": 5},
    }
    for key, value in changes.items():
        node = cfg
        *path, last = key.split(".")
        for part in path:
            node = node[part]
        node[last] = value
    return cfg


def test_standard_grid_trainings_in_table_order() -> None:
    cells = training_cells(config()["grid"])
    assert [c.id for c in cells] == [
        "train/source_only_s0",
        "train/source_only_s1",
        "train/source_only_s2",
        *(f"train/adaptsegnet_n{n}_s{s}" for n in (4, 5, 6, 7) for s in (0, 1, 2)),
    ]
    adapted = cells[7]
    assert adapted.config == "adaptsegnet_n5" and adapted.model == "adaptsegnet_n5_s1"
    assert adapted.overrides() == [
        "model/method=adaptsegnet",
        "seed=1",
        "run_name=adaptsegnet_n5_s1",
        "model.method.discriminator.n_layers=5",
    ]
    assert cells[0].overrides() == ["model/method=source_only", "seed=0", "run_name=source_only_s0"]


def test_loss_weight_lists_multiply_the_adapted_grid_only() -> None:
    grid = config(
        **{
            "grid.loss": {"lambda_adv_main": [0.001, 0.01], "lambda_seg_aux": [0.1]},
            "grid.n_layers": [5],
            "grid.seeds": [0],
        }
    )["grid"]
    cells = training_cells(grid)
    # source-only ignores the adversarial weights: one training, with the pinned seg weight
    assert [c.model for c in cells] == [
        "source_only_s0",
        "adaptsegnet_n5_adv_main0.001_s0",
        "adaptsegnet_n5_adv_main0.01_s0",
    ]
    assert cells[0].overrides()[-1] == "model.loss.lambda_seg_aux=0.1"
    assert cells[1].overrides()[-2:] == [
        "model.method.lambda_adv_main=0.001",
        "model.loss.lambda_seg_aux=0.1",
    ]
    assert cells[2].describe()["loss"] == "lambda_adv_main=0.01;lambda_seg_aux=0.1"


def test_loss_combinations_are_the_product_in_order() -> None:
    combos = loss_combinations({"lambda_adv_main": [1, 2], "lambda_adv_aux": [3, 4]})
    assert combos == [
        (("lambda_adv_main", 1.0), ("lambda_adv_aux", 3.0)),
        (("lambda_adv_main", 1.0), ("lambda_adv_aux", 4.0)),
        (("lambda_adv_main", 2.0), ("lambda_adv_aux", 3.0)),
        (("lambda_adv_main", 2.0), ("lambda_adv_aux", 4.0)),
    ]
    assert loss_combinations({}) == [()]


def test_slam_runs_semantic_for_every_model_geometry_for_the_compared_ones() -> None:
    grid = expand(config(), SYNTHETIC_SEQUENCES)
    assert len(grid.trainings) == 15 and len(grid.segevals) == 15
    assert grid.table_configs == ("source_only", "adaptsegnet_n5")
    per_sequence = [s for s in grid.slams if s.sequence == "walking_rpy"]
    counts: dict[str, int] = {}
    for s in per_sequence:
        counts[s.variant] = counts.get(s.variant, 0) + 1
    # model-free: 1 each; semantic: all 15 models; geometry variants: 3 + 3 compared models
    assert counts == {
        "none": 1,
        "semantic": 15,
        "geometry": 1,
        "semantic_geometry": 6,
        "semantic_geometry_object": 6,
        "oracle": 1,
    }
    assert len(grid.slams) == 4 * 30
    ids = {s.id for s in grid.slams}
    assert "slam/harness/walking_rpy/none" in ids
    assert "slam/harness/walking_rpy/semantic_geometry/adaptsegnet_n5_s2" in ids
    assert "slam/harness/walking_rpy/semantic_geometry/adaptsegnet_n4_s2" not in ids
    every = expand(config(**{"slam.every_model": True}), SYNTHETIC_SEQUENCES)
    assert len(every.slams) == 4 * (3 + 3 * 15)


def test_orbslam3_gets_the_mask_variants_only() -> None:
    grid = expand(
        config(systems=["harness", "orbslam3"], sequences=["walking_xyz"]), SYNTHETIC_SEQUENCES
    )
    orb = {s.variant for s in grid.slams if s.system == "orbslam3"}
    assert orb == {"none", "semantic", "oracle"}
    assert sum(s.system == "orbslam3" for s in grid.slams) == 2 + 15


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"grid.methods": ["source_only", "dann"]},
         f"grid.methods[1]: expected one of {', '.join(method_names())}, got 'dann'"),
        ({"grid.methods": ["adaptsegnet", "adaptsegnet"]},
         "grid.methods: expected a non-empty list of source_only, "),
        ({"sequences": ["walking_xyz", "office"]}, "sequences[1]: expected one of walking_xyz, "),
        ({"sequences": ["walking_xyz", "sitting_xyz"]},
         "sequences: unknown value 'sitting_xyz'; accepted: " + ", ".join(SYNTHETIC_SEQUENCES)),
        ({"variants": ["none", "flow"]}, "variants[1]: expected one of none, "),
        ({"systems": ["orbslam2"]}, "systems[0]: expected one of harness, orbslam3, got 'orbslam2'"),
        ({"systems": ["harness", "harness"]}, "systems: expected a non-empty list of harness, "),
        ({"grid.n_layers": [4, 9]}, "grid.n_layers[1]: expected an integer >= 1 and <= 8, got 9"),
        ({"grid.seeds": []}, "grid.seeds: expected a non-empty list of integers >= 0 and <= "
         "4294967295, each once, got []"),
        ({"grid.seeds": [0, 0]}, "grid.seeds: expected a non-empty list of integers >= 0 and <= "
         "4294967295, each once (0 is listed twice), got [0, 0]"),
        ({"grid.loss": {"lambda_gan": [1]}},
         "grid.loss: unknown value 'lambda_gan'; accepted: lambda_seg_aux, lambda_seg_main, "
         "lambda_adv_aux, lambda_adv_main"),
        ({"grid.loss": {"lambda_adv_main": ["big"]}},
         "grid.loss.lambda_adv_main: expected a number, got 'big'"),
        ({"tables.n_layers": 3}, "tables.n_layers: 3 is not a depth of the grid; accepted: 4, 5, 6, 7"),
    ],
)  # fmt: skip
def test_bad_keys_are_one_line_naming_the_key(changes: dict[str, Any], message: str) -> None:
    """The schema checks each key's values (as ``uss-experiments`` does first), the grid the
    rules across keys and the user's own mappings."""
    cfg = config(**changes)
    with pytest.raises(UssSlamError) as info:
        check(cfg, ExperimentsSchema)
        expand(cfg, SYNTHETIC_SEQUENCES)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_train_cell_without_depth_is_source_only_shaped() -> None:
    cell = TrainCell("source_only", seed=3)
    assert (cell.config, cell.model, cell.id) == (
        "source_only",
        "source_only_s3",
        "train/source_only_s3",
    )


def test_a_users_own_scale_or_launcher_file_is_an_accepted_option(tmp_path) -> None:
    """``uss-experiments --config-dir DIR scale=mine``: DIR/scale/mine.yaml is an option, as
    Hydra itself will find it; a name in neither folder is still one line."""
    from uss_slam.pipelines.experiments.experiment import check_choices

    (tmp_path / "scale").mkdir()
    (tmp_path / "scale" / "mine.yaml").write_text("scale_name: mine\n")
    check_choices(["--config-dir", str(tmp_path), "scale=mine"])
    check_choices([f"--config-dir={tmp_path}", "scale=quick"])
    with pytest.raises(UssSlamError, match=r"^scale: unknown value 'mine'; accepted: "):
        check_choices(["scale=mine"])

"""The methods axis of the uss-experiments grid: every shipped adaptation method is a row of the
tables; depths and adversarial loss weights apply to the methods with discriminators only; the
geometry variants stay with the models T2 / T3 compare."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir

from uss_slam.pipelines.experiments.grid import (
    DISCRIMINATOR_METHODS,
    METHODS,
    expand,
    training_cells,
)

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
ALL = ["source_only", "adaptsegnet", "advent", "minent", "self_training"]


def _grid(**changes: object) -> dict:
    return {"methods": ALL, "n_layers": [4, 5], "seeds": [0], "loss": {}, **changes}


def test_every_shipped_method_is_in_the_grid() -> None:
    shipped = sorted(p.stem for p in (CONFIG_DIR / "model" / "method").glob("*.yaml"))
    assert sorted(METHODS) == shipped
    for name, overrides in METHODS.items():
        assert overrides == (f"model/method={name}",)
    assert set(DISCRIMINATOR_METHODS) == {"adaptsegnet", "advent"}


def test_methods_axis_trainings() -> None:
    cells = training_cells(_grid())
    assert [c.model for c in cells] == [
        "source_only_s0",
        "adaptsegnet_n4_s0",
        "adaptsegnet_n5_s0",
        "advent_n4_s0",
        "advent_n5_s0",
        "minent_s0",
        "self_training_s0",
    ]
    advent = cells[4]
    assert advent.overrides() == [
        "model/method=advent",
        "seed=0",
        "run_name=advent_n5_s0",
        "model.discriminator.n_layers=5",
    ]
    assert cells[-1].overrides() == [
        "model/method=self_training",
        "seed=0",
        "run_name=self_training_s0",
    ]


def test_adversarial_weights_only_for_methods_with_discriminators() -> None:
    cells = training_cells(
        _grid(n_layers=[5], loss={"lambda_adv_main": [0.001, 0.01], "lambda_seg_aux": 0.4})
    )
    by_method: dict[str, list[str]] = {}
    for c in cells:
        by_method.setdefault(c.method, []).append(c.model)
    assert by_method["advent"] == ["advent_n5_adv_main0.001_s0", "advent_n5_adv_main0.01_s0"]
    assert by_method["minent"] == ["minent_s0"]
    assert by_method["self_training"] == ["self_training_s0"]
    minent = next(c for c in cells if c.method == "minent")
    assert "model.loss.lambda_seg_aux=0.4" in minent.overrides()
    assert not any("lambda_adv" in o for o in minent.overrides())


def test_geometry_variants_stay_with_the_compared_models() -> None:
    cfg = {
        "grid": _grid(n_layers=[5]),
        "sequences": ["walking_xyz"],
        "variants": ["none", "semantic", "semantic_geometry"],
        "systems": ["harness"],
        "slam": {"every_model": False},
        "tables": {"n_layers": 5},
    }
    grid = expand(cfg, ["walking_xyz"])
    assert grid.table_configs == ("source_only", "adaptsegnet_n5")
    semantic = {c.model.model for c in grid.slams if c.variant == "semantic"}
    assert semantic == {t.model for t in grid.trainings}  # T1: every method's ATE
    geometry = {c.model.model for c in grid.slams if c.variant == "semantic_geometry"}
    assert geometry == {"source_only_s0", "adaptsegnet_n5_s0"}
    assert len(grid.segevals) == 5


def test_experiments_config_accepts_the_methods_axis() -> None:
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("experiments", overrides=[f"grid.methods=[{','.join(ALL)}]"])
    assert list(cfg.grid.methods) == ALL
    assert list(dict.fromkeys(c.method for c in training_cells(cfg.grid))) == ALL

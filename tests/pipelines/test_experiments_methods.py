"""The methods axis of the uss-experiments grid: every shipped adaptation method is a row of the
tables; depths and adversarial loss weights apply to the methods with discriminators only; the
geometry variants stay with the models T2 / T3 compare."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from uss_slam.core.errors import UssSlamError
from uss_slam.core.schema import check
from uss_slam.pipelines.experiments.grid import (
    METHODS,
    discriminator_methods,
    expand,
    training_cells,
)
from uss_slam.pipelines.experiments.schema import Grid

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
ALL = ["source_only", "adaptsegnet", "advent", "minent", "self_training"]


def _grid(**changes: object) -> dict:
    return {"methods": ALL, "n_layers": [4, 5], "seeds": [0], "loss": {}, **changes}


def test_every_shipped_method_is_in_the_grid() -> None:
    shipped = sorted(p.stem for p in (CONFIG_DIR / "model" / "method").glob("*.yaml"))
    assert sorted(METHODS) == shipped and next(iter(METHODS)) == "source_only"
    for name, overrides in METHODS.items():
        assert overrides == (f"model/method={name}",)
    # from the classes' trains_discriminators, in the grid's order
    assert discriminator_methods() == ("adaptsegnet", "advent")


def test_methods_axis_trainings() -> None:
    # the default depth sweep: AdaptSegNet at every depth, the other methods at tables.n_layers
    cells = training_cells(_grid(), 5)
    assert [c.model for c in cells] == [
        "source_only_s0",
        "adaptsegnet_n4_s0",
        "adaptsegnet_n5_s0",
        "advent_n5_s0",
        "minent_s0",
        "self_training_s0",
    ]
    advent = cells[3]
    assert advent.overrides() == [
        "model/method=advent",
        "seed=0",
        "run_name=advent_n5_s0",
        "model.method.discriminator.n_layers=5",
    ]
    assert cells[-1].overrides() == [
        "model/method=self_training",
        "seed=0",
        "run_name=self_training_s0",
    ]
    swept = training_cells(_grid(depth_sweep=["adaptsegnet", "advent"]), 5)
    assert [c.model for c in swept if c.method == "advent"] == ["advent_n4_s0", "advent_n5_s0"]
    assert [c.model for c in training_cells(_grid(depth_sweep=[]), 4)] == [
        "source_only_s0",
        "adaptsegnet_n4_s0",
        "advent_n4_s0",
        "minent_s0",
        "self_training_s0",
    ]


def test_standard_scale_with_every_method_costs_24_trainings() -> None:
    # 3 source-only + 4 depths x 3 AdaptSegNet + 3 x (ADVENT at n = 5, MinEnt, self-training)
    grid = {"methods": ALL, "n_layers": [4, 5, 6, 7], "seeds": [0, 1, 2], "loss": {}}
    cells = training_cells({**grid, "depth_sweep": ["adaptsegnet"]}, 5)
    assert len(cells) == 3 + 12 + 3 * 3 == 24
    assert {c.n_layers for c in cells if c.method == "advent"} == {5}
    assert len(training_cells({**grid, "depth_sweep": ["adaptsegnet", "advent"]}, 5)) == 33


@pytest.mark.parametrize(
    ("changes", "n_table", "message"),
    [
        (
            {"depth_sweep": ["minent"]},
            5,
            "grid.depth_sweep[0]: expected one of adaptsegnet, advent, got 'minent'",
        ),
        ({"depth_sweep": "adaptsegnet"}, 5, "grid.depth_sweep: expected a list of adaptsegnet"),
        (
            {"depth_sweep": ["advent", "advent"]},
            5,
            "grid.depth_sweep: expected a list of adaptsegnet, advent, each once ('advent' is "
            "listed twice)",
        ),
        (
            {"depth_sweep": []},
            None,
            "tables.n_layers: expected a discriminator depth 1..8, got None",
        ),
        ({}, 6, "tables.n_layers: 6 is not a depth of the grid; accepted: 4, 5"),
    ],
)
def test_bad_depth_sweep_is_one_line(changes: dict, n_table: object, message: str) -> None:
    with pytest.raises(UssSlamError) as info:  # the schema's values, then the grid's rules
        check(_grid(**changes), Grid, "grid")
        training_cells(_grid(**changes), n_table)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_adversarial_weights_only_for_methods_with_discriminators() -> None:
    cells = training_cells(
        _grid(n_layers=[5], loss={"lambda_adv_main": [0.001, 0.01], "lambda_seg_aux": 0.4}), 5
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
    assert list(dict.fromkeys(c.method for c in training_cells(cfg.grid, 5))) == ALL


def _job_keys(tmp_path: Path, *overrides: str) -> dict[str, dict]:
    """Every job id of a ``uss-experiments`` config -> its cache key (data and exports faked:
    the keys only read their names)."""
    from uss_slam.pipelines.experiments import experiment
    from uss_slam.pipelines.experiments.data import Data
    from uss_slam.pipelines.experiments.plan import plan_slam, plan_train

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("experiments", overrides=[f"out_dir={tmp_path}", *overrides])
    exp = experiment.check(cfg)
    names = exp.grid.sequences
    data = Data(
        train_key={"demo": "key"},
        train_dir=tmp_path / "data" / "train",
        sequences={n: tmp_path / "data" / "eval" / n for n in names},
        sequence_keys={n: {"sequence": n} for n in names},
        labelled=list(names),
    )
    exports = {t.model: f"sha256-of-{t.model}" for t in exp.grid.trainings}
    jobs = plan_train(exp, data) + plan_slam(exp, data, exports)
    exp.train_specs.update({j.id: j.spec for j in jobs})
    return {j.id: j.spec["key"] for j in jobs}


CRF_VARIANTS = "variants=[none,semantic,geometry,semantic_geometry,semantic_geometry_object,oracle,semantic_crf,semantic_geometry_crf]"


def test_more_methods_and_crf_variants_keep_every_job_key(tmp_path: Path) -> None:
    from uss_slam.pipelines.runs import slam_defaults_key

    pytest.importorskip("pydensecrf")
    base = _job_keys(tmp_path, "scale=standard_full")
    more = _job_keys(
        tmp_path, "scale=standard_full", f"grid.methods=[{','.join(ALL)}]", CRF_VARIANTS
    )
    # every job of the default grid is a job of the bigger one, with the same key: a run of
    # the default grid is reused by a rerun with more methods and the CRF variants
    assert {k: more[k] for k in base} == base
    added = sorted(set(more) - set(base))
    trainings = [k for k in added if k.startswith("train/")]
    assert trainings == [
        f"train/{m}_s{s}" for m in ("advent_n5", "minent", "self_training") for s in range(3)
    ]
    # the keys the default grid has had (a change would redo a finished standard run)
    assert base["train/adaptsegnet_n5_s0"]["overrides"] == [
        "experiment=demo",
        "paths.log_dir=$OUT",
        "paths.data_dir=$OUT/data/train",
        "logger=none",
        "callbacks.image_logger=null",
        "++trainer.enable_progress_bar=false",
        "model/method=adaptsegnet",
        "model.method.lambda_adv_aux=0.02",  # tum_like's tuned settings (grid.method_overrides)
        "model.method.lambda_adv_main=0.1",
        "seed=0",
        "run_name=adaptsegnet_n5_s0",
        "model.method.discriminator.n_layers=5",
    ]
    assert base["segeval/adaptsegnet_n5_s0"] == {
        "model": "sha256-of-adaptsegnet_n5_s0",
        "sequences": {n: {"sequence": n} for n in STANDARD_SEQUENCES},
        "stride": 5,
    }
    semantic = "slam/harness/walking_xyz/semantic/adaptsegnet_n5_s0"
    model = "$OUT/exports/adaptsegnet_n5_s0/adaptsegnet_n5_s0.onnx"
    assert base[semantic] == {
        "overrides": [
            "sequence.path=$OUT/data/eval/walking_xyz",
            "segmenter=onnx",
            f"segmenter.path={model}",
            "filters=[semantic]",
            "slam.repeats=3",  # the median of three harness runs per job
        ],
        "defaults": slam_defaults_key(),
        "sequence": {"sequence": "walking_xyz"},
        "model": "sha256-of-adaptsegnet_n5_s0",
    }
    crf = more["slam/harness/walking_xyz/semantic_crf/adaptsegnet_n5_s0"]
    plain = base[semantic]["overrides"][:-1]
    assert crf["overrides"] == [*plain, "segmenter.crf=true", "slam.repeats=3"]
    assert more["segeval/crf/adaptsegnet_n5_s0"] == {**base["segeval/adaptsegnet_n5_s0"], "crf": {}}
    # CRF runs and metrics for the models T2 / T3 compare only
    crf_models = {k.rsplit("/", 1)[1] for k in added if "crf" in k}
    assert crf_models == {f"{c}_s{s}" for c in ("source_only", "adaptsegnet_n5") for s in range(3)}
    assert len([k for k in added if k.startswith("slam/") and "_crf/" in k]) == 4 * 2 * 6


STANDARD_SEQUENCES = ("walking_xyz", "walking_rpy", "walking_halfsphere", "static_xyz")


def test_standard_scale_is_the_full_grid_trimmed(tmp_path: Path) -> None:
    # scale=standard is the grid that fits about 2 h on two cores (the paper's depth only, three
    # sequences, four filter variants, ORB-SLAM3 beside the harness); its trainings and harness
    # jobs are jobs of scale=standard_full with the same keys, so either run reuses the other's
    full = _job_keys(tmp_path, "scale=standard_full")
    std = _job_keys(tmp_path, "scale=standard")
    trainings = sorted(k for k in std if k.startswith("train/"))
    assert trainings == sorted(
        f"train/{m}_s{s}" for m in ("source_only", "adaptsegnet_n5", "oracle") for s in range(3)
    )
    harness = {k: v for k, v in std.items() if k.startswith(("train/", "slam/harness/"))}
    harness = {k: v for k, v in harness.items() if "_adabn_" not in k}
    assert {k: full.get(k) for k in harness} == harness
    slam = [k.split("/") for k in std if k.startswith("slam/")]
    assert {s[2] for s in slam} == {"walking_xyz", "walking_rpy", "static_xyz"}
    assert {s[3] for s in slam} == {"none", "semantic", "semantic_geometry", "oracle"}
    assert {s[1] for s in slam} == {"harness", "orbslam3"}
    # AdaptSegNet's weights with target statistics are a row of the trimmed grid's T0
    assert "slam/harness/walking_xyz/semantic/adaptsegnet_n5_adabn_s0" in std
    assert not any(k.startswith("slam/orbslam3/") for k in full)


def test_converged_scale_is_the_standard_grid_trained_longer(tmp_path: Path) -> None:
    std = _job_keys(tmp_path, "scale=standard")
    conv = _job_keys(tmp_path, "scale=converged")
    # the same jobs (rows, seeds, sequences, filters, systems) ...
    assert set(conv) == set(std)
    trainings = [k for k in std if k.startswith("train/")]
    assert len(trainings) == 9
    for k in trainings:
        # ... every training six times the standard budget, with the speed setting that picks
        # bf16 on CPUs that have it, its other overrides unchanged
        longer = ["model.max_iters=7200", "trainer=fast_cpu"]
        assert conv[k]["overrides"] == [*std[k]["overrides"][:6], *longer,
                                        *std[k]["overrides"][6:]]  # fmt: skip
        assert not set(longer) & set(std[k]["overrides"])
    # the SLAM jobs run as standard's (keyed by their exported models' hashes: new jobs)
    job = "slam/harness/walking_xyz/semantic/source_only_s0"
    assert conv[job]["overrides"] == std[job]["overrides"]


def test_slam_job_keys_hold_the_uss_slam_defaults(tmp_path: Path, monkeypatch) -> None:
    # A SLAM job's cache key holds uss-slam's default settings as well as its overrides, so a
    # rerun after a default changed (another tracker policy, say) redoes the SLAM jobs and
    # keeps the trainings.
    from uss_slam.pipelines.experiments import plan
    from uss_slam.pipelines.runs import slam_defaults_key

    before = _job_keys(tmp_path, "scale=quick")
    slam_ids = [k for k, key in before.items() if "defaults" in key]
    assert slam_ids and all(before[k]["defaults"] == slam_defaults_key() for k in slam_ids)
    monkeypatch.setattr(plan, "slam_defaults_key", lambda: "other defaults")
    after = _job_keys(tmp_path, "scale=quick")
    assert {k for k in before if before[k] != after[k]} == set(slam_ids)


def test_method_overrides_go_into_that_methods_trainings_only() -> None:
    settings = {"adaptsegnet": ["model.domain_batch_norm=running"], "oracle": ["model.lr=1e-3"]}
    cells = training_cells(_grid(methods=["source_only", "adaptsegnet"], n_layers=[5],
                                 method_overrides=settings), 5)  # fmt: skip
    assert cells[0].overrides() == ["model/method=source_only", "seed=0", "run_name=source_only_s0"]
    assert cells[1].overrides() == [
        "model/method=adaptsegnet",
        "model.domain_batch_norm=running",
        "seed=0",
        "run_name=adaptsegnet_n5_s0",
        "model.method.discriminator.n_layers=5",
    ]
    # the config name (and so the tables' row and the folder) stays the method's
    assert [c.model for c in cells] == ["source_only_s0", "adaptsegnet_n5_s0"]


def test_each_shift_preset_trains_with_its_tuned_settings(tmp_path: Path) -> None:
    from uss_slam.pipelines.experiments.grid import PRESET_METHOD_OVERRIDES

    tum = _job_keys(tmp_path, "scale=standard")
    # tum_like (the default): ten times the adversarial weights, the BatchNorm mode unchanged
    assert "model.domain_batch_norm=running" not in tum["train/adaptsegnet_n5_s0"]["overrides"]
    assert list(PRESET_METHOD_OVERRIDES["tum_like"]["adaptsegnet"]) == [
        o
        for o in tum["train/adaptsegnet_n5_s0"]["overrides"]
        if o.startswith("model.method.lambda")
    ]
    assert not any("lambda_adv" in o for o in tum["train/source_only_s0"]["overrides"])
    app = _job_keys(tmp_path, "scale=standard", "data.synthetic.shift=appearance")
    tuned = list(PRESET_METHOD_OVERRIDES["appearance"]["adaptsegnet"])
    assert tuned and all(t in app["train/adaptsegnet_n5_s0"]["overrides"] for t in tuned)
    assert not set(tuned) & set(app["train/source_only_s0"]["overrides"])
    # {} turns the preset's settings off; a mapping given replaces them
    paper = _job_keys(tmp_path, "scale=standard", "data.synthetic.shift=appearance",
                      "grid.method_overrides={}")  # fmt: skip
    assert not set(tuned) & set(paper["train/adaptsegnet_n5_s0"]["overrides"])
    own = _job_keys(tmp_path, "scale=standard", "data.synthetic.shift=appearance",
                    "grid.method_overrides={adaptsegnet:['model.domain_batch_norm=joint']}")  # fmt: skip
    assert "model.domain_batch_norm=joint" in own["train/adaptsegnet_n5_s0"]["overrides"]
    assert not set(tuned) & set(own["train/adaptsegnet_n5_s0"]["overrides"])


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (
            {"mystery": ["a=1"]},
            "grid.method_overrides: unknown value 'mystery'; accepted: source_only",
        ),
        (["a=1"], "grid.method_overrides: expected a mapping of method"),
        ({"adaptsegnet": "a=1"}, "grid.method_overrides.adaptsegnet: expected a list of key=value"),
        (
            {"adaptsegnet": ["novalue"]},
            "grid.method_overrides.adaptsegnet: expected key=value overrides, got 'novalue'",
        ),
    ],
)
def test_bad_method_overrides_are_one_line(value: object, message: str) -> None:
    with pytest.raises(UssSlamError, match="^" + message.replace("(", r"\(").replace("[", r"\[")):
        training_cells(_grid(method_overrides=value), 5)

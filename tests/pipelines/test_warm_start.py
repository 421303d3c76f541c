"""The warm-start protocol of uss-experiments (``init``): the plan's training ids, overrides and
cache keys with and without a pretrained init (scratch exactly as before), the pretraining jobs,
and the one-line errors of bad ``init`` / ``grid.batchnorm`` keys. scale=quick's warm start end to
end (its tiny pretrained init) is test_experiments_slow's, on its scale=quick run."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines.experiments import data, experiment, plan, warm_start
from uss_slam.pipelines.experiments.experiment import CONFIG_DIR

SHA = {0: "a" * 64, 1: "b" * 64}


def compose_experiments(*overrides: str):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("experiments", overrides=list(overrides))


def check(tmp_path: Path, *overrides: str) -> experiment.Experiment:
    return experiment.check(compose_experiments(f"out_dir={tmp_path}", *overrides))


def staged(exp: experiment.Experiment, tmp_path: Path) -> data.Data:
    """The data stage's result, with each init as the data stage records it."""
    found = data.Data(train_dir=tmp_path / "data" / "train", train_key="demo.yaml")
    for k in exp.init.seeds:
        found.init[k] = tmp_path / "data" / "init" / f"i{k}" / "init.ckpt"
        found.init_keys[k] = SHA[k]
    return found


def test_scratch_plan_is_the_plan_without_warm_start(tmp_path: Path) -> None:
    exp = check(tmp_path, "init.kind=scratch", "grid.seeds=[0,1]")
    assert not exp.init.pretrained and exp.init.seeds == ()
    jobs = plan.plan_train(exp, staged(exp, tmp_path))
    assert [j.id for j in jobs] == [
        "train/source_only_s0",
        "train/source_only_s1",
        *(f"train/adaptsegnet_n{n}_s{s}" for n in (4, 5, 6, 7) for s in (0, 1)),
        "train/oracle_s0",
        "train/oracle_s1",
    ]
    adapted = next(j for j in jobs if j.id == "train/adaptsegnet_n5_s1")
    # the overrides and key every training had before the warm start existed
    assert adapted.spec["key"] == {
        "overrides": [
            "experiment=ci",
            "paths.log_dir=$OUT",
            "paths.data_dir=$OUT/data/train",
            "logger=none",
            "callbacks.image_logger=null",
            "++trainer.enable_progress_bar=false",
            "model/method=adaptsegnet",
            "model.method.lambda_adv_aux=0.02",
            "model.method.lambda_adv_main=0.1",
            "seed=1",
            "run_name=adaptsegnet_n5_s1",
            "model.method.discriminator.n_layers=5",
        ],
        "data": "demo.yaml",
    }
    assert adapted.spec["overrides"] == [
        o.replace("$OUT", str(exp.out)) for o in adapted.spec["key"]["overrides"]
    ] + ["num_threads=1"]
    assert not any("weights_path" in o for j in jobs for o in j.spec["overrides"])
    assert all(set(j.spec["key"]) == {"overrides", "data"} for j in jobs)
    assert warm_start.describe_init(exp) is None


def test_one_init_keeps_the_ids_and_adds_weights_and_sha(tmp_path: Path) -> None:
    scratch = check(tmp_path, "init.kind=scratch")
    exp = check(tmp_path)  # scale=quick: a pretrained init
    assert exp.init.pretrains and exp.init.seeds == (0,)
    before = {j.id: j for j in plan.plan_train(scratch, staged(scratch, tmp_path))}
    jobs = plan.plan_train(exp, staged(exp, tmp_path))
    assert [j.id for j in jobs] == list(before)
    weights = f"model.net.weights_path={tmp_path / 'data' / 'init' / 'i0' / 'init.ckpt'}"
    for job in jobs:  # every row (source-only, the methods, the oracle) starts from the init
        old = before[job.id]
        assert job.spec["overrides"] == [*old.spec["overrides"][:-1], weights, "num_threads=1"]
        assert job.spec["key"] == {
            "overrides": [*old.spec["key"]["overrides"], "model.net.weights_path="
                          "$OUT/data/init/i0/init.ckpt"],
            "data": "demo.yaml",
            "init": SHA[0],
        }  # fmt: skip
        assert job.row["init"] == 0
    # AdaBN is an export of source-only's checkpoint: it inherits the init
    assert {c.source.init for c in exp.grid.adabn} == {0}


def test_two_inits_name_their_rows_and_keys(tmp_path: Path) -> None:
    exp = check(tmp_path, "init.seeds=[0,1]", "grid.seeds=[0]", "grid.n_layers=[5]")
    jobs = plan.plan_train(exp, staged(exp, tmp_path))
    assert [j.id for j in jobs] == [
        "train/source_only_i0_s0",
        "train/source_only_i1_s0",
        "train/adaptsegnet_n5_i0_s0",
        "train/adaptsegnet_n5_i1_s0",
        "train/oracle_i0_s0",
        "train/oracle_i1_s0",
    ]
    for job in jobs:
        k = job.row["init"]
        assert job.id.endswith(f"_i{k}_s0") and job.row["config"].endswith(f"_i{k}")
        assert job.spec["key"]["init"] == SHA[k]
        assert (
            f"model.net.weights_path=$OUT/data/init/i{k}/init.ckpt"
            in (job.spec["key"]["overrides"])
        )
    # the same seed from another init: another training (its own run name and key)
    assert jobs[0].spec["key"] != jobs[1].spec["key"]
    assert "run_name=source_only_i1_s0" in jobs[1].spec["overrides"]
    assert [c.model for c in exp.grid.adabn] == ["adabn_i0_s0", "adabn_i1_s0"]


def test_pretraining_jobs_are_keyed_by_set_experiment_overrides_and_seed(tmp_path: Path) -> None:
    exp = check(tmp_path, "init.seeds=[0,3]")
    pretrain = warm_start.pretrain_set_stage(exp)
    assert pretrain.folder == exp.out / "data" / "pretrain"
    assert dict(pretrain.key) == {
        "images": 64,
        "size": "160x120",
        "seed": 900,
        "lighting": "source",
        "outfits": "all",
        "near": 0.3,
    }
    jobs = warm_start.init_jobs(exp, pretrain)
    assert [j.id for j in jobs] == ["data/init/i0", "data/init/i3"]
    spec = jobs[1].spec
    assert spec["key"] == {
        "overrides": [
            "experiment=pretrain",
            "data.source.root=$OUT/data/pretrain/VOCdevkit/VOC2012",
            "seed=3",
            "run_name=init_i3",
            "paths.log_dir=$OUT",
            "model.max_iters=8",
            "data.iterations_per_epoch=4",
            "data.num_workers=0",
            "logger=none",
            "callbacks.image_logger=null",
            "++trainer.enable_progress_bar=false",
        ],
        "pretrain": dict(pretrain.key),
    }
    assert spec["kind"] == "train" and spec["init"] == "init.ckpt"
    assert "init.ckpt" in spec["outputs"]
    other = warm_start.init_jobs(
        check(tmp_path, "init.seeds=[0,3]", "init.images=65"), pretrain
    )  # the same set folder, other keys: only through the set's key
    assert other[1].spec["key"]["pretrain"] == dict(pretrain.key)
    again = warm_start.init_jobs(
        check(tmp_path, "init.seeds=[0,3]", "init.images=65"),
        warm_start.pretrain_set_stage(check(tmp_path, "init.images=65")),
    )
    assert again[1].spec["key"]["pretrain"]["images"] == 65
    plan_text = warm_start.describe_init(exp)
    assert plan_text is not None
    assert plan_text.splitlines()[:3] == [
        "init: 2 jobs, 0 complete, 2 to run",
        "  to run: data/init/i0",
        "  to run: data/init/i3",
    ]


def test_pretraining_style_is_in_the_key_and_the_real_regime_refuses_mixed(tmp_path: Path) -> None:
    real = warm_start.pretrain_set_stage(check(tmp_path))
    assert real.key["lighting"] == "source" and real.key["outfits"] == "all"
    legacy = check(tmp_path, "init.style=mixed", "init.regime=legacy")
    key = warm_start.pretrain_set_stage(legacy).key
    # the earlier tables' pretraining set, key for key
    assert key == {"images": 64, "size": "160x120", "seed": 900, "lighting": "mixed",
                   "outfits": "all", "near": 0.3}  # fmt: skip
    assert "init.regime=legacy" in warm_start.init_header(legacy)
    assert "source lighting and camera only" in warm_start.init_header(check(tmp_path))
    with pytest.raises(UssSlamError, match=r"^init\.style: mixed renders half of the "):
        check(tmp_path, "init.style=mixed")
    with pytest.raises(UssSlamError, match="init.style: expected one of 'source', 'mixed'"):
        check(tmp_path, "init.style=target", "init.regime=legacy")


def test_missing_init_is_an_error_unless_dry(tmp_path: Path) -> None:
    exp = check(tmp_path, "stages=[train]")
    found = data.Data(train_dir=tmp_path / "data" / "train")
    with pytest.raises(Exception, match="missing or incomplete pretraining set"):
        warm_start.stage_init(exp, found, run=False)
    status = warm_start.stage_init(exp, found, run=False, dry=True)
    assert "pretraining set to render" in status and "pretrained init i0: to train" in status
    assert found.init_keys == {0: None}


def test_init_path_is_every_trainings_start(tmp_path: Path) -> None:
    weights = tmp_path / "coco_init.pth"
    weights.write_bytes(b"PK\x03\x04 weights")  # torch.save's zip, as far as the check reads
    exp = check(tmp_path, f"init.path={weights}", "init.kind=pretrained", "grid.seeds=[0]")
    assert exp.init.path == weights and not exp.init.pretrains
    found = data.Data(train_dir=tmp_path / "data" / "train")
    assert warm_start.stage_init(exp, found, run=False) == f"pretrained init {weights} (init.path)"
    jobs = plan.plan_train(exp, found)
    assert [j.id for j in jobs][:1] == ["train/source_only_s0"]  # no pretraining, one init
    for job in jobs:
        assert f"model.net.weights_path={weights}" in job.spec["overrides"]
        assert job.spec["key"]["init"] == hashlib.sha256(weights.read_bytes()).hexdigest()
    assert warm_start.describe_init(exp) is None


def test_batchnorm_modes_are_rows_of_their_own(tmp_path: Path) -> None:
    exp = check(
        tmp_path,
        "grid.batchnorm={adaptsegnet:[trained,reference]}",
        "grid.seeds=[0]",
        "grid.n_layers=[5]",
    )
    jobs = plan.plan_train(exp, staged(exp, tmp_path))
    assert [j.id for j in jobs] == [
        "train/source_only_s0",
        "train/adaptsegnet_n5_bntrained_s0",
        "train/adaptsegnet_n5_bnreference_s0",
        "train/oracle_s0",
    ]
    modes = {j.id: [o for o in j.spec["overrides"] if o.startswith("model.net.batchnorm=")]
             for j in jobs}  # fmt: skip
    assert modes["train/adaptsegnet_n5_bnreference_s0"] == ["model.net.batchnorm=reference"]
    assert modes["train/source_only_s0"] == []
    assert jobs[2].row["batchnorm"] == "reference" and jobs[2].row["config"] == (
        "adaptsegnet_n5_bnreference"
    )


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["init.kind=imagenet"], "init.kind: expected one of 'scratch', 'pretrained', got 'imagenet'"),
        (["init.path=/nonexistent/coco.pth"], "init.path=/nonexistent/coco.pth: does not exist"),
        (["init.render_seed=3"], "init.render_seed: 3 is a seed of the source set or of a sequence"),
        (["init.render_seed=1000"], "init.render_seed: 1000 is a seed of the source set or of a"),
        (["init.seeds=[0,0]"], "init.seeds: expected a non-empty list of integers >= 0 and <= 4294967295, each once (0 is listed twice)"),
        (["init.seeds=[]"], "init.seeds: expected a non-empty list"),
        (["init.images=0"], "init.images: expected an integer >= 2, got 0"),
        (["init.size=big"], "init.size: "),
        (["init.experiment=nope"], "init.experiment: expected one of 'ci', 'demo', "),
        (["init.overrides=[max_iters]"], "init.overrides: expected key=value overrides, got 'max_iters'"),
        (
            ["scale=paper", "data.real.voc=/v", "data.real.sbd=/s", "data.real.coco=/c",
             "data.real.tum=/t"],
            "init.path: missing; data.kind=real with init.kind=pretrained needs the pretrained "
            "weights file",
        ),
        (
            ["grid.batchnorm={dann:[trained]}"],
            "grid.batchnorm: unknown value 'dann'; accepted: source_only, adaptsegnet",
        ),
        (
            ["grid.batchnorm={adaptsegnet:[sync]}"],
            "grid.batchnorm.adaptsegnet: mode 'sync' is not one of the network's (DeepLabV2); "
            "accepted: auto, trained, frozen, reference",
        ),
        (
            ["grid.batchnorm={adaptsegnet:[reference]}", 'train.overrides=["model/net=pspnet_small"]'],
            "grid.batchnorm.adaptsegnet: mode 'reference' is not one of the network's (PSPNet); "
            "accepted: auto, trained, frozen",
        ),
        (["grid.batchnorm={adaptsegnet:[]}"], "grid.batchnorm.adaptsegnet: expected a non-empty"),
    ],
)  # fmt: skip
def test_bad_init_or_batchnorm_is_one_line(
    tmp_path: Path, overrides: list[str], message: str
) -> None:
    with pytest.raises(UssSlamError) as info:
        check(tmp_path, *overrides)
    assert str(info.value).startswith(message), str(info.value)
    assert "\n" not in str(info.value)


def test_scratch_ignores_the_pretraining_keys_and_paper_takes_a_file(tmp_path: Path) -> None:
    # scratch: no pretraining is planned from the init keys (their values are still checked
    # against the schema: a bad one is an error in any mode)
    assert not check(tmp_path, "init.kind=scratch", "init.images=3").init.pretrained
    weights = tmp_path / "init.pth"
    weights.write_bytes(b"PK\x03\x04")
    paper = check(
        tmp_path,
        "scale=paper",
        *(f"data.real.{k}={tmp_path}" for k in ("voc", "sbd", "coco", "tum")),
        f"init.path={weights}",
    )
    assert paper.init.path == weights and paper.grid.trainings[0].init is None


def test_an_init_path_torch_cannot_read_is_one_line_in_a_dry_run(tmp_path: Path) -> None:
    """An ONNX model as ``init.path`` was accepted until the init stage loaded it."""
    model = tmp_path / "m.onnx"
    model.write_bytes(b"\x08\x08\x12\x07pytorch")  # how an exported ONNX model starts
    with pytest.raises(UssSlamError, match=rf"^init.path={model}: not a file torch.load reads"):
        check(tmp_path, f"init.path={model}", "init.kind=pretrained", "dry_run=true")

"""T0, the standard UDA table of uss-experiments: its reference jobs (the target oracle's
training, AdaBN's export, the source-validation evaluations) planned or not per flag with keys
that follow their inputs, the table's arithmetic (means over sequences, closure paired by seed,
standard errors, marking), and its keys' one-line errors."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from PIL import Image
from pipeline_helpers import colour_model, tiny_run
from shared_helpers import colour_labels

from uss_slam.core.classes import CLASS_NAMES, voc_lut
from uss_slam.core.errors import UssSlamError
from uss_slam.core.seg_metrics import confusion_matrix, iou_per_class
from uss_slam.pipelines.experiments import cli, experiment, grid, jobs, launch, plan
from uss_slam.pipelines.experiments import tables as tbl
from uss_slam.pipelines.experiments.data import Data
from uss_slam.pipelines.runs import compose_config
from uss_slam.train.method_configs import method_names

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
PROG = [sys.executable, "-m", "uss_slam.pipelines.experiments.cli"]
TARGET = ("walking_xyz", "walking_rpy", "walking_halfsphere", "sitting_static")


def compose_experiments(*overrides: str):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("experiments", overrides=list(overrides))


def checked(tmp_path: Path, *overrides: str) -> experiment.Experiment:
    return experiment.check(
        compose_experiments(f"out_dir={tmp_path}", "grid.seeds=[0,1]", *overrides)
    )


def synthetic_data(out: Path, record: str = "seed: 0\n") -> Data:
    """The synthetic data as the data stage finds it (nothing read from disk)."""
    train = out / "data" / "train"
    data = Data(
        train_key=record, train_dir=train, target=[train / "target_train" / t for t in TARGET]
    )
    data.source_val, data.source_val_key = train / "voc", record
    for name in ("walking_xyz", "static_xyz"):
        data.sequences[name] = out / "data" / "eval" / name
        data.sequence_keys[name] = {"preset": name}
        data.labelled.append(name)
    return data


def planned(exp: experiment.Experiment, data: Data) -> tuple[list, list]:
    trainings = plan.plan_train(exp, data)
    exp.train_specs.update({j.id: j.spec for j in trainings})
    return trainings, plan.plan_slam(exp, data, {})


# ------------------------------------------------------------------------------------ planning


def test_t0_jobs_are_planned_per_flag(tmp_path: Path) -> None:
    data = synthetic_data(tmp_path)
    exp = checked(tmp_path, "grid.n_layers=[4,5]")
    assert exp.cfg["grid"]["oracle"] is True  # null = true for synthetic data
    trainings, slam = planned(exp, data)
    assert [j.id for j in trainings][-2:] == ["train/oracle_s0", "train/oracle_s1"]
    assert [c.model for c in exp.grid.adabn] == ["adabn_s0", "adabn_s1"]
    ids = {j.id for j in slam}
    # T0's rows (source-only, AdaBN, the adapted model at tables.n_layers, oracle) on the
    # source val split; not the other depths
    assert {i for i in ids if i.startswith("segeval/source_val/")} == {
        f"segeval/source_val/{m}_s{s}"
        for m in ("source_only", "adaptsegnet_n5", "oracle", "adabn")
        for s in (0, 1)
    }
    for model in ("adabn_s1", "oracle_s1"):  # scored like every model: segeval + semantic runs
        assert f"segeval/{model}" in ids
        assert f"slam/harness/walking_xyz/semantic/{model}" in ids
    # semantic+geometry for AdaBN (the baseline any method must beat, in the downstream ratio
    # of both its filters), not for the oracle; no other geometry variant
    assert "slam/harness/walking_xyz/semantic_geometry/adabn_s1" in ids
    assert "slam/harness/walking_xyz/semantic_geometry/oracle_s1" not in ids
    assert not any("semantic_geometry_object/adabn" in i for i in ids)
    row = next(j.row for j in slam if j.id == "segeval/source_val/adabn_s0")
    assert (row["method"], row["config"], row["seed"], row["sequence"]) == (
        "adabn",
        "adabn",
        0,
        tbl.SOURCE_VAL,
    )

    off = checked(
        tmp_path, "grid.oracle=false", "grid.adabn=false", "segeval.source_val_stride=null"
    )
    trainings, slam = planned(off, data)
    assert [j.id for j in trainings] == [
        f"train/{m}_s{s}" for m in ("source_only", "adaptsegnet_n4", "adaptsegnet_n5",
                                    "adaptsegnet_n6", "adaptsegnet_n7") for s in (0, 1)
    ]  # fmt: skip
    assert off.grid.adabn == ()
    assert not any("oracle_s" in j.id or "adabn" in j.id or "source_val" in j.id for j in slam)
    # without source-only there is nothing to apply AdaBN to
    assert checked(tmp_path, "grid.methods=[adaptsegnet]").grid.adabn == ()


def test_adabn_of_a_methods_checkpoint_is_its_own_model(tmp_path: Path) -> None:
    data = synthetic_data(tmp_path)
    exp = checked(tmp_path, "grid.n_layers=[4,5]", "grid.adabn_methods=[source_only,adaptsegnet]")
    # at the tables' depth only, named after the method's configuration
    assert [c.model for c in exp.grid.adabn] == [
        "adabn_s0", "adabn_s1", "adaptsegnet_n5_adabn_s0", "adaptsegnet_n5_adabn_s1"
    ]  # fmt: skip
    cell = exp.grid.adabn[2]
    assert cell.source.model == "adaptsegnet_n5_s0"
    assert cell.describe()["method"] == "adabn" and cell.config == "adaptsegnet_n5_adabn"
    _, slam = planned(exp, data)
    assert plan.adabn_stage(exp, data, cell) is None  # waits for its training, as source-only's
    ids = {j.id for j in slam}
    assert {"segeval/adaptsegnet_n5_adabn_s0", "segeval/source_val/adaptsegnet_n5_adabn_s0",
            "slam/harness/walking_xyz/semantic/adaptsegnet_n5_adabn_s0"} <= ids  # fmt: skip
    # the default adds nothing to the grid recorded runs have
    assert [c.model for c in checked(tmp_path).grid.adabn] == ["adabn_s0", "adabn_s1"]


def test_oracle_trains_source_only_on_the_labelled_target_frames(tmp_path: Path) -> None:
    data = synthetic_data(tmp_path)
    exp = checked(tmp_path, "grid.methods=[source_only]")
    cells = {c.model: c for c in exp.grid.trainings}
    source, _ = plan.train_overrides(exp, data, cells["source_only_s0"])
    # source-only's overrides (and so its cache key) are what they were before T0
    assert source == [
        "experiment=ci",
        f"paths.log_dir={exp.out}",
        f"paths.data_dir={data.train_dir}",
        "logger=none",
        "callbacks.image_logger=null",
        "++trainer.enable_progress_bar=false",
        "model/method=source_only",
        "seed=0",
        "run_name=source_only_s0",
    ]
    oracle, runtime = plan.train_overrides(exp, data, cells["oracle_s1"])
    roots = ",".join(str(p) for p in data.target)
    assert oracle == [
        *source[:6],
        "model/method=source_only",
        "seed=1",
        "run_name=oracle_s1",
        "~data.source",
        "+data.source={_target_:uss_slam.datasets.tum.TUMFrames,roots:[" + roots + "],"
        "labels:true,transform:{_target_:uss_slam.datasets.transforms.train_transform,"
        "crop_size:129,scale_range:[0.75,1.25],hflip:true}}",
        "++callbacks.precise_bn=null",
    ]
    assert runtime == ["num_threads=1"]
    # what uss-train composes from them: the same net and budget, target frames with labels
    cfg = compose_config("train", oracle)
    assert cfg.data.source.labels is True and list(cfg.data.source.roots) == roots.split(",")
    assert cfg.data.source.transform.crop_size == 129 and cfg.model.max_iters == 4
    assert cfg.callbacks.precise_bn is None and cfg.model.net.backbone == "resnet_small"


def test_t0_cache_keys_follow_their_inputs(tmp_path: Path) -> None:
    data = synthetic_data(tmp_path)
    exp = checked(tmp_path, "grid.methods=[source_only]")
    trainings, slam = planned(exp, data)
    keys = {j.id: j.spec["key"] for j in trainings}
    # the oracle's key holds its data (the labelled target folders) and the source's crops
    assert any("target_train/walking_xyz" in o for o in keys["train/oracle_s0"]["overrides"])
    assert all(str(tmp_path) not in o for o in keys["train/oracle_s0"]["overrides"])
    crops = checked(tmp_path, "grid.methods=[source_only]",
                    'train.overrides=["data.source.transform.crop_size=97"]')  # fmt: skip
    crops_keys = {j.id: j.spec["key"] for j in plan.plan_train(crops, data)}
    assert crops_keys["train/oracle_s0"] != keys["train/oracle_s0"]
    assert any("crop_size:97" in o for o in crops_keys["train/oracle_s0"]["overrides"])

    # the source val evaluation: the model, the VOC tree (data key) and the stride
    seg = {j.id: j for j in slam}["segeval/source_val/source_only_s0"]
    assert seg.spec["source_val"] == {"root": str(data.source_val), "split": "val", "stride": 1}
    assert seg.spec["key"] == {
        "model": None,
        "source_val": {"data": "seed: 0\n", "split": "val", "stride": 1},
    }
    exports = {"source_only_s0": "sha-a"}
    again = {j.id: j for j in plan.plan_slam(exp, synthetic_data(tmp_path, "seed: 5\n"), exports)}
    assert again[seg.id].spec["key"]["model"] == "sha-a"
    assert again[seg.id].spec["key"]["source_val"]["data"] == "seed: 5\n"
    strided = checked(tmp_path, "grid.methods=[source_only]", "segeval.source_val_stride=4")
    planned(strided, data)
    key = {j.id: j for j in plan.plan_slam(strided, data, {})}[seg.id].spec["key"]
    assert key["source_val"]["stride"] == 4

    # AdaBN: nothing until source-only's training is complete, then its checkpoint's export
    # key plus the target frames its statistics come from
    adabn = exp.grid.model("adabn_s0")
    assert plan.adabn_stage(exp, data, adabn) is None
    folder = tmp_path / "train" / "source_only_s0"
    (folder / "checkpoints").mkdir(parents=True)
    (folder / "checkpoints" / "last.ckpt").write_bytes(b"weights")
    (folder / jobs.RESULT).write_text("{}")
    jobs.stage_of(exp.out, exp.train_specs["train/source_only_s0"], "train/source_only_s0").finish()
    source = plan.export_stage(exp, exp.grid.training("source_only_s0"))
    stage = plan.adabn_stage(exp, data, adabn)
    assert source is not None and stage is not None
    assert stage.folder == tmp_path / "exports" / "adabn_s0"
    assert {k: v for k, v in stage.key.items() if k != "adabn"} == source.key
    assert stage.key["adabn"] == {
        "images": 48,
        "batch_size": 4,
        "target": [f"$OUT/data/train/target_train/{t}" for t in TARGET],
    }
    fewer = synthetic_data(tmp_path)
    fewer.target = fewer.target[:2]
    assert plan.adabn_stage(exp, fewer, adabn).key != stage.key
    # a checkpoint rewritten (another training) changes it too
    (folder / "checkpoints" / "last.ckpt").write_bytes(b"other weights")
    assert plan.adabn_stage(exp, data, adabn).key != stage.key


def test_adabn_jobs_wait_for_source_only(tmp_path: Path) -> None:
    data = synthetic_data(tmp_path)
    exp = checked(tmp_path, "grid.methods=[source_only]")
    _, slam = planned(exp, data)
    blocked = plan.blocked_jobs(exp, slam, {}, {})
    assert blocked["segeval/adabn_s0"] == (
        "needs exports/adabn_s0: training train/source_only_s0 has no result"
    )
    assert (
        plan.blocked_jobs(exp, slam, {}, {"adabn_s1": "boom"})[
            "slam/harness/static_xyz/semantic/adabn_s1"
        ]
        == "needs exports/adabn_s1: its export failed"
    )
    assert blocked["segeval/source_val/oracle_s1"] == (
        "needs exports/oracle_s1: training train/oracle_s1 has no result"
    )
    text = launch.describe_plan(exp, "slam", slam, set(blocked))
    assert "  after exports/oracle_s0: segeval/oracle_s0, segeval/source_val/oracle_s0, " in text


# ------------------------------------------------------------------------------------ jobs


def test_source_val_segeval_scores_the_voc_val_split(tmp_path: Path, synthetic_voc) -> None:
    voc = synthetic_voc(images=15, size=(96, 72), seed=4)  # val: every fifth image = 3
    model = colour_model(tmp_path / "colour.onnx", bias=120.0)
    spec = {"model": str(model), "source_val": {"root": str(voc), "split": "val", "stride": 2}}
    result = jobs.run_segeval(tmp_path / "job", spec)
    assert list(result["sequences"]) == [tbl.SOURCE_VAL]  # no pooled "all"
    scores = result["sequences"][tbl.SOURCE_VAL]
    # the same, counted here from the files: val images 0 and 2
    names = (voc / "ImageSets" / "Segmentation" / "val.txt").read_text().split()[::2]
    n = len(CLASS_NAMES)
    matrix = np.zeros((n, n), np.int64)
    for name in names:
        bgr = cv2.imread(str(voc / "JPEGImages" / f"{name}.jpg"))
        truth = voc_lut()[np.asarray(Image.open(voc / "SegmentationClass" / f"{name}.png"))]
        matrix += confusion_matrix(truth, colour_labels(bgr[..., ::-1], 120.0), n)
    assert scores["frames"] == 2
    iou = iou_per_class(matrix)
    assert scores["mIoU"] == pytest.approx(float(np.nanmean(iou)))
    assert scores["IoU"]["person"] == pytest.approx(float(iou[CLASS_NAMES.index("person")]))
    job = plan.Job("segeval/source_val/m", {**spec, "kind": "segeval"},
                   {"kind": "segeval", "sequence": tbl.SOURCE_VAL})  # fmt: skip
    [row] = launch.result_rows(job, "ok", "", result, ["walking_xyz"])
    assert row["sequence"] == tbl.SOURCE_VAL and row["mIoU"] == scores["mIoU"]
    [blocked] = launch.result_rows(job, "blocked", "needs x", {}, ["walking_xyz"])
    assert blocked["sequence"] == tbl.SOURCE_VAL and blocked["status"] == "blocked"


def test_adabn_export_has_target_batchnorm_statistics(tmp_path: Path, synthetic_sequence) -> None:
    import onnx
    import torch

    from uss_slam.core.onnx_contract import SegmenterMetadata
    from uss_slam.datasets.transforms import eval_transform
    from uss_slam.datasets.tum import TUMFrames
    from uss_slam.export import export_checkpoint, load_checkpoint
    from uss_slam.train.precise_bn import adabn

    ckpt = tiny_run(tmp_path / "run")
    target = [synthetic_sequence(preset="walking_xyz", frames=6, size=(64, 48))]
    cell = grid.AdaBNCell(grid.TrainCell("source_only", 3))
    options = cli._adabn_options(Data(target=target), cell)
    assert options["experiment"] == "adabn_s3"
    seen = []
    export_checkpoint(ckpt, tmp_path / "adabn.onnx", **{**options, "prepare": seen.append})
    assert len(seen) == 1 and isinstance(seen[0], torch.nn.Module)  # the hook gets the net
    out = tmp_path / "adabn.onnx"
    export_checkpoint(ckpt, out, **options)
    plain = tmp_path / "plain.onnx"
    export_checkpoint(ckpt, plain)
    # the exported statistics are those adabn() computes on the target frames
    expected = load_checkpoint(ckpt).segmenter
    adabn(expected, TUMFrames(target, transform=eval_transform()), images=48, batch_size=4)
    image = np.random.default_rng(0).integers(0, 256, (1, 40, 56, 3), np.uint8)

    def logits(path: Path) -> np.ndarray:
        import onnxruntime as ort

        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        return session.run(["logits"], {"image": image})[0]

    from uss_slam.export import SegmenterExport

    with torch.no_grad():
        eager = SegmenterExport(expected.eval(), head="main")(torch.from_numpy(image))[0].numpy()
    assert np.abs(logits(out) - eager).max() < 1e-3
    assert np.abs(logits(out) - logits(plain)).max() > 1e-2
    meta = SegmenterMetadata.from_props(
        {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    )
    assert meta.experiment == "adabn_s3"
    assert meta.checkpoint_sha256 == load_checkpoint(ckpt).sha256


# ------------------------------------------------------------------------------------ the table


def _t0_rows(failed_adapted_seed: int | None = None) -> list[dict]:
    """Source-only, AdaBN, AdaptSegNet (n = 5) and the oracle over seeds 0-2 on two sequences:
    per-sequence mIoU = base[config][seed] + offset[sequence]; person IoU defined on
    walking_xyz only (static_xyz has no people)."""
    base = {
        "source_only": (0.20, 0.30, 0.25),
        "adabn": (0.26, 0.33, 0.28),
        "adaptsegnet_n5": (0.24, 0.36, 0.26),
        "oracle": (0.40, 0.50, 0.30),
    }
    person = {"source_only": 0.1, "adabn": 0.2, "adaptsegnet_n5": 0.3, "oracle": 0.5}
    offset = {"walking_xyz": -0.05, "static_xyz": 0.05}
    rows: list[dict] = []
    for config, values in base.items():
        method, _, n = config.partition("_n")
        common = {"method": method, "n_layers": int(n) if n else None, "config": config}
        for seed, value in enumerate(values):
            model = f"{config}_s{seed}"
            if config != "adabn":
                rows.append({"kind": "train", "id": f"train/{model}", "status": "ok", **common,
                             "seed": seed, "val_mIoU": 0.1})  # fmt: skip
            bad = config == "adaptsegnet_n5" and seed == failed_adapted_seed
            seg = {"kind": "segeval", "status": "blocked" if bad else "ok", **common, "seed": seed}
            for sequence, delta in offset.items():
                rows.append({**seg, "id": f"segeval/{model}", "sequence": sequence,
                             "mIoU": None if bad else value + delta,
                             "IoU_person": None if bad or sequence == "static_xyz"
                             else person[config] + 0.1 * seed,
                             "person_FNR": None if bad else 0.5, "crf": 0})  # fmt: skip
            rows.append({**seg, "id": f"segeval/{model}", "sequence": "all", "mIoU": 0.9, "crf": 0})
            rows.append({**seg, "id": f"segeval/source_val/{model}", "sequence": tbl.SOURCE_VAL,
                         "mIoU": None if bad else 0.6 + 0.01 * seed, "crf": 0})  # fmt: skip
            rows.append({"kind": "slam", "id": f"slam/harness/walking_xyz/semantic/{model}",
                         "status": "ok", **common, "seed": seed, "system": "harness",
                         "sequence": "walking_xyz", "variant": "semantic",
                         "ate_rmse": 0.01 * (seed + 1)})  # fmt: skip
    return rows


def test_t0_closure_is_paired_by_seed_with_standard_errors(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    tbl.write_runs(path, _t0_rows())
    rows = tbl.read_runs(path)
    layout = tbl.layout_from_rows(rows, 5)
    assert (layout.adabn, layout.oracle) == (("adabn",), "oracle")
    # the oracle is T0's only: no row of T1 or of T2 by method
    assert layout.configs == ("source_only", "adaptsegnet_n5")
    assert layout.sequences == ("walking_xyz", "static_xyz")
    data, text = tbl.compute(rows, 5)
    t0 = {r["config"]: r for r in data["T0"]["rows"]}
    assert list(t0) == ["source_only", "adabn", "adaptsegnet_n5", "oracle"]
    assert [r["role"] for r in t0.values()] == ["source-only", "AdaBN", "method", "oracle"]
    # the mean over the two sequences is the base value (offsets cancel), per seed
    assert t0["adaptsegnet_n5"]["mIoU"]["per_seed"] == {
        "0": pytest.approx(0.24), "1": pytest.approx(0.36), "2": pytest.approx(0.26)
    }  # fmt: skip
    # closure per seed: (0.24-0.20)/(0.40-0.20), (0.36-0.30)/(0.50-0.30), (0.26-0.25)/(0.30-0.25)
    closure = t0["adaptsegnet_n5"]["closure_mIoU"]
    per_seed = [0.2, 0.3, 0.2]
    assert [closure["per_seed"][s] for s in "012"] == pytest.approx(per_seed)
    mean = sum(per_seed) / 3
    se = math.sqrt(sum((v - mean) ** 2 for v in per_seed) / 2) / math.sqrt(3)
    assert closure["mean"] == pytest.approx(mean) and closure["se"] == pytest.approx(se)
    # ... not the closure of the means over seeds
    assert closure["mean"] != pytest.approx((0.2867 - 0.25) / (0.4 - 0.25), abs=1e-3)
    assert t0["source_only"]["closure_mIoU"]["values"] == [0.0, 0.0, 0.0]
    assert t0["oracle"]["closure_mIoU"]["values"] == [1.0, 1.0, 1.0]
    adabn = t0["adabn"]["closure_mIoU"]["per_seed"]
    assert [adabn[s] for s in "012"] == pytest.approx([0.3, 0.15, 0.6])
    # person IoU: only walking_xyz defines it; its closure (0.3+0.1s-0.1-0.1s)/(0.4)
    assert t0["adaptsegnet_n5"]["IoU_person"]["values"] == pytest.approx([0.3, 0.4, 0.5])
    assert t0["adaptsegnet_n5"]["closure_IoU_person"]["values"] == pytest.approx([0.5] * 3)
    assert t0["oracle"]["source_val_mIoU"]["values"] == pytest.approx([0.60, 0.61, 0.62])
    assert t0["oracle"]["person_FNR"]["mean"] == pytest.approx(0.5)
    assert t0["adabn"]["ate_rmse"][0]["mean"] == pytest.approx(0.02)
    assert t0["adabn"]["ate_rmse"][0]["se"] == pytest.approx(0.01 / math.sqrt(3))

    assert text.startswith("### T0: the UDA table")
    assert (
        f"| adaptsegnet_n5 | none | 0.610 ± 0.006 (n=3) | 0.287 ± 0.037 (n=3) | 0.400 ± 0.058 "
        f"(n=3) | {mean:.3f} ± {se:.3f} (n=3) | 0.500 ± 0.000 (n=3) |"
    ) in text
    assert "| oracle † | training | " in text  # trained with target labels
    assert "| adabn | 0 | 0.600 | 0.260 | 0.200 | 0.300 | 0.250 |" in text  # per seed
    assert "| adabn | 2 | 0.620 | 0.280 | 0.400 | 0.600 | 0.250 |" in text


def test_a_methods_adabn_row_follows_the_method(tmp_path: Path) -> None:
    rows = _t0_rows()
    for r in [r for r in rows if r.get("config") == "adabn"]:
        mine = {**r, "config": "adaptsegnet_n5_adabn",
                "id": r["id"].replace("adabn_s", "adaptsegnet_n5_adabn_s")}  # fmt: skip
        rows.append(mine)
    path = tmp_path / "runs.csv"
    tbl.write_runs(path, rows)
    data, text = tbl.compute(tbl.read_runs(path), 5)
    assert [(r["config"], r["role"]) for r in data["T0"]["rows"]] == [
        ("source_only", "source-only"), ("adabn", "AdaBN"), ("adaptsegnet_n5", "method"),
        ("adaptsegnet_n5_adabn", "AdaBN"), ("oracle", "oracle"),
    ]  # fmt: skip
    assert "<method>_adabn" in text


def test_t0_counts_failed_seeds_and_marks_target_label_selection(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    tbl.write_runs(path, _t0_rows(failed_adapted_seed=1))
    rows = tbl.read_runs(path)
    data, text = tbl.compute(rows, 5, policy="best_target_val")
    t0 = {r["config"]: r for r in data["T0"]["rows"]}
    closure = t0["adaptsegnet_n5"]["closure_mIoU"]
    assert (closure["n"], closure["failed"]) == (2, 1)
    assert closure["per_seed"] == {"0": pytest.approx(0.2), "2": pytest.approx(0.2)}
    assert "(n=2, 1 failed)" in text
    # every checkpoint was chosen with target labels: every row says so
    labels = {c: r["target_labels"] for c, r in t0.items()}
    assert labels == {
        "source_only": "checkpoint selection",
        "adabn": "checkpoint selection",
        "adaptsegnet_n5": "checkpoint selection",
        "oracle": "training, checkpoint selection",
    }
    assert "| source_only † | checkpoint selection | " in text
    assert data["T0"]["policy"] == "best_target_val"


def test_t0_without_oracle_has_no_closure_and_an_oracle_no_better_gives_none() -> None:
    rows = [r for r in _t0_rows() if r.get("config") != "oracle"]
    data, text = tbl.compute(rows, 5)
    t0 = {r["config"]: r for r in data["T0"]["rows"]}
    assert list(t0) == ["source_only", "adabn", "adaptsegnet_n5"]
    assert t0["adabn"]["closure_mIoU"]["n"] == 0
    assert "no oracle in this run (grid.oracle=false): no closure" in text
    assert tbl.closure(0.3, 0.2, 0.2) is None and tbl.closure(0.3, 0.2, 0.1) is None
    assert tbl.closure(0.1, 0.2, 0.4) == pytest.approx(-0.5)  # worse than source-only
    assert tbl.closure(None, 0.2, 0.4) is None
    none = tbl.compute([r for r in rows if r.get("method") == "adaptsegnet"], 5)[1]
    assert "Not computed: needs source_only in grid.methods." in none


def test_stat_standard_error() -> None:
    s = tbl.Stat((0.1, 0.2, 0.3))
    assert s.se == pytest.approx(0.1 / math.sqrt(3))
    assert s.text(3, "se") == "0.200 ± 0.058 (n=3)" and s.text(3) == "0.200 ± 0.100 (n=3)"
    assert tbl.Stat((0.5,)).se is None and tbl.Stat((0.5,)).text(3, "se") == "0.500 (n=1)"


# ------------------------------------------------------------------------------------ errors


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["grid.oracle=maybe"], "grid.oracle: expected true or false or null, got 'maybe'"),
        (["grid.adabn=1"], "grid.adabn: expected true or false, got 1"),
        (
            ["grid.adabn_methods=[mystery]"],
            f"grid.adabn_methods[0]: expected one of {', '.join(method_names())}, got 'mystery'",
        ),
        (
            ["grid.adabn_methods=[]"],
            f"grid.adabn_methods: expected a non-empty list of {', '.join(method_names())}, got []",
        ),
        (
            ["segeval.source_val_stride=0"],
            "segeval.source_val_stride: expected an integer >= 1 or null, got 0",
        ),
    ],
)
def test_bad_t0_key_is_one_line(overrides: list[str], message: str) -> None:
    with pytest.raises(UssSlamError) as info:
        experiment.check(compose_experiments(*overrides))
    assert str(info.value) == message


def _real(tmp_path: Path, *extra: str) -> list[str]:
    tum = tmp_path / "tum"
    for name in ("walking_xyz", "sitting_static"):
        (tum / f"rgbd_dataset_freiburg3_{name}").mkdir(parents=True, exist_ok=True)
    return [
        "scale=paper",
        f"data.real.voc={tmp_path}",
        f"data.real.sbd={tmp_path}",
        f"data.real.coco={tmp_path}",
        f"data.real.tum={tum}",
        "data.real.target=[walking_xyz,sitting_static]",
        "init.kind=scratch",  # (scale=paper's warm start needs an init file)
        *extra,
    ]


def test_real_data_oracle_needs_target_labels(tmp_path: Path) -> None:
    exp = experiment.check(compose_experiments(*_real(tmp_path)))
    assert exp.cfg["grid"]["oracle"] is False  # null = false for real data
    assert not any(t.method == grid.ORACLE for t in exp.grid.trainings)
    with pytest.raises(UssSlamError) as info:
        experiment.check(compose_experiments(*_real(tmp_path, "grid.oracle=true")))
    labels = tmp_path / "tum" / "rgbd_dataset_freiburg3_walking_xyz" / "labels"
    assert str(info.value) == (
        "grid.oracle: the target oracle trains on labelled target frames, but data.real.target "
        f"sequence walking_xyz has no labels/ ({labels}); set grid.oracle=false"
    )
    for name in ("walking_xyz", "sitting_static"):
        (tmp_path / "tum" / f"rgbd_dataset_freiburg3_{name}" / "labels").mkdir()
    labelled = experiment.check(compose_experiments(*_real(tmp_path, "grid.oracle=true")))
    assert [t.model for t in labelled.grid.trainings if t.method == grid.ORACLE] == [
        "oracle_s0",
        "oracle_s1",
        "oracle_s2",
    ]


def test_console_script_real_oracle_without_labels_is_one_line_no_work(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(
        [*PROG, f"out_dir={out}", *_real(tmp_path, "grid.oracle=true")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 1  # as every config error of uss-experiments
    assert proc.stderr.strip().startswith("uss-experiments: error: grid.oracle: the target oracle")
    assert "\n" not in proc.stderr.strip()
    assert not (out / "data").exists() and not (out / "train").exists()


def test_t0_header_says_what_its_rows_are(tmp_path: Path) -> None:
    data = synthetic_data(tmp_path)
    exp = checked(tmp_path)
    [line] = cli._t0_header(exp, data)
    assert line == (
        "- T0: AdaBN on 48 evenly spaced target training frames; oracle trained on the labelled "
        "target training frames; in domain: the source VOC tree's val split (1 image in 1), "
        "held out from training"
    )
    seen = checked(tmp_path, "grid.oracle=false", 'train.overrides=["data.source.split=trainval"]')
    [line] = cli._t0_header(seen, data)
    assert "no oracle (grid.oracle=false: no closure)" in line
    assert line.endswith("NOT held out: the trainings read it")
    assert json.dumps(line)  # one line


def test_the_downstream_ratio_has_the_adabn_and_oracle_models(tmp_path: Path) -> None:
    """T0's AdaBN models (no training of their own: their seeds come from their SLAM runs) and
    the target oracle get downstream ratios and paired differences to source-only, as the
    trained models do."""
    rows = _t0_rows()
    for variant, ate in (("none", 0.1), ("oracle", 0.02)):  # the model-free baselines
        rows.append({"kind": "slam", "id": f"slam/harness/walking_xyz/{variant}", "status": "ok",
                     "system": "harness", "sequence": "walking_xyz", "variant": variant,
                     "ate_rmse": ate})  # fmt: skip
    for r in rows:  # AdaBN's masks do better than source-only's by 0.01 m on every seed
        if r["kind"] == "slam" and r.get("config") == "adabn":
            r["ate_rmse"] -= 0.01
    path = tmp_path / "runs.csv"
    tbl.write_runs(path, rows)
    data, text = tbl.compute(tbl.read_runs(path), 5)
    ratio = {
        (r["config"], r["seed"]): r["ratio"]
        for r in data["downstream_ratio"]
        if r["sequence"] == "walking_xyz"
    }
    for seed in (0, 1, 2):
        so = (0.1 - 0.01 * (seed + 1)) / 0.08
        assert ratio[("source_only", seed)] == pytest.approx(so)
        assert ratio[("adabn", seed)] == pytest.approx(so + 0.125)
        assert ratio[("oracle", seed)] == pytest.approx(so)
    paired = {
        r["config"]: r for r in data["downstream_ratio_paired"] if r["sequence"] == "walking_xyz"
    }
    assert set(paired) == {"adabn", "adaptsegnet_n5", "oracle"}
    assert paired["adabn"]["mean"] == pytest.approx(0.125)
    assert "| adabn | − source_only | +0.12 / +0.12 / +0.13 (3/3 > 0), mean +0.13" in text

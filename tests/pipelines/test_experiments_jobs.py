"""uss-experiments' jobs and checks: one job's cache stamp and failure record, the state of a
job read back from its folder, the Hydra override quoting, and every bad input as one line
before any work starts."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import write_json_atomic
from uss_slam.core.ranges import MAX_THREADS
from uss_slam.pipelines.experiments import data, experiment, jobs, launch, plan
from uss_slam.pipelines.runs import SlamJob
from uss_slam.train.method_configs import method_names

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
PROG = [sys.executable, "-m", "uss_slam.pipelines.experiments.cli"]


def compose_experiments(*overrides: str):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose("experiments", overrides=list(overrides))


def slam_plan(tmp_path: Path, sequence: Path, cells: dict[str, str]) -> Path:
    """A plan of SLAM jobs (id -> sequence path) as uss-experiments writes it."""
    specs = {
        cell: {
            "kind": "slam",
            "job": SlamJob(Path(path)).to_json(),
            "key": {"sequence": str(path)},
            "outputs": ["metrics.json"],
        }
        for cell, path in cells.items()
    }
    plan_file = tmp_path / "jobs" / "slam.json"
    write_json_atomic(plan_file, {"stage": "slam", "out": str(tmp_path), "cells": specs})
    return plan_file


# ------------------------------------------------------------------------------------ jobs


def test_a_job_stamps_its_result_and_is_reused(
    tmp_path: Path, synthetic_sequence: Callable[..., Path]
) -> None:
    seq = synthetic_sequence(preset="static_xyz", frames=12)
    plan_file = slam_plan(tmp_path, seq, {"slam/harness/static_xyz/none": str(seq)})
    result = jobs.run_cell(plan_file, tmp_path, "slam/harness/static_xyz/none")
    assert result["status"] == "ok"
    folder = tmp_path / "slam/harness/static_xyz/none"
    record = json.loads((folder / jobs.RESULT).read_text())
    metrics = json.loads((folder / "metrics.json").read_text())
    assert record["ate"] == metrics["ate"] and record["seconds"] > 0
    assert json.loads((folder / ".uss-demo.json").read_text()) == {"sequence": str(seq)}
    assert jobs.run_cell(plan_file, tmp_path, "slam/harness/static_xyz/none") == {
        "status": "reused"
    }


def test_a_failed_job_records_why_and_raises_nothing(
    tmp_path: Path, synthetic_sequence: Callable[..., Path]
) -> None:
    seq = synthetic_sequence(preset="static_xyz", frames=12)
    missing = tmp_path / "no_such_sequence"
    plan_file = slam_plan(tmp_path, seq, {"slam/a": str(missing), "slam/b": str(seq)})
    failed = jobs.run_cell(plan_file, tmp_path, "slam/a")
    assert failed["status"] == "failed" and str(missing) in failed["reason"]
    record = json.loads((tmp_path / "slam/a" / jobs.FAILURE).read_text())
    assert record["reason"] == failed["reason"] and "Traceback" in record["traceback"]
    assert not (tmp_path / "slam/a" / ".uss-demo.json").exists()
    assert jobs.run_cell(plan_file, tmp_path, "slam/b")["status"] == "ok"  # the other job runs


def test_reason_is_one_line() -> None:
    assert jobs.reason_of(UssSlamError("x.png: not found\nmore")) == "x.png: not found"
    assert jobs.reason_of(ValueError("a 8-layer discriminator needs ...")) == (
        "ValueError: a 8-layer discriminator needs ..."
    )
    assert jobs.reason_of(MemoryError()) == "MemoryError"


def test_status_from_the_folder(tmp_path: Path) -> None:
    exp = experiment.check(compose_experiments(f"out_dir={tmp_path}"))
    spec = {"kind": "slam", "key": {"k": 1}, "outputs": ["metrics.json"]}
    job = plan.Job("slam/x", spec, {"kind": "slam"})
    launched = {"slam": launch.Launch(pending=["slam/x"], returncode=1)}
    status, reason, _ = launch.status_of(exp, job, {}, launched)
    assert status == "missing" and "killed or interrupted" in reason and "exit code 1" in reason
    assert launch.status_of(exp, job, {}, {})[:2] == ("missing", launch.NOT_RUN)
    assert launch.status_of(exp, job, {"slam/x": "needs exports/m"}, launched)[:2] == (
        "blocked",
        "needs exports/m",
    )
    folder = tmp_path / "slam/x"
    write_json_atomic(folder / jobs.FAILURE, {"reason": "boom", "seconds": 1.0})
    assert launch.status_of(exp, job, {}, launched)[:2] == ("failed", "boom (log: logs/slam/x.log)")
    (folder / "metrics.json").write_text("{}")
    write_json_atomic(folder / jobs.RESULT, {"ate": None})
    write_json_atomic(folder / ".uss-demo.json", {"k": 1})
    assert launch.status_of(exp, job, {}, launched)[0] == "ok"  # complete wins over a stale record
    # a SLAM run's time per frame comes from its metrics.json (also for runs finished earlier)
    timing = {"segmentation": 52.0, "segmentation.crf": 41.5, "orb": 9.0, "total": 70.0}
    (folder / "metrics.json").write_text(json.dumps({"timing_ms": timing}))
    status, _, result = launch.status_of(exp, job, {}, launched)
    assert result == {"ate": None, "timing_ms": timing}
    [row] = launch.result_rows(job, status, "", result, ["walking_xyz"])
    assert (row["segmentation_ms"], row["crf_ms"], row["total_ms"]) == (52.0, 41.5, 70.0)


# ------------------------------------------------------------------------------------ checks


def test_hydra_override_values_are_quoted_when_needed() -> None:
    assert (
        launch.hydra_value("train/adaptsegnet_n5_adv_main0.001_s0")
        == "train/adaptsegnet_n5_adv_main0.001_s0"
    )
    assert launch.hydra_value("/data/my runs/x") == "'/data/my runs/x'"
    assert launch.hydra_value("it's") == "'it\\'s'"
    assert launch.hydra_value("true") == "'true'" and launch.hydra_value("1e5") == "'1e5'"
    assert (
        launch.hydra_value(4) == "4"
        and launch.hydra_value(None) == "null"
        and launch.hydra_value(True) == "true"
    )
    assert launch.hydra_value(["a", 2]) == "[a,2]"


def test_launcher_overrides_merge_the_stage_section() -> None:
    exp = experiment.check(compose_experiments("launcher=slurm", "launcher.params.partition=gpu"))
    train = launch.launcher_overrides(exp, "train")
    slam = launch.launcher_overrides(exp, "slam")
    assert train[0] == slam[0] == "hydra/launcher=submitit_slurm"
    assert "hydra.launcher.partition=gpu" in train and "hydra.launcher.gpus_per_node=1" in train
    assert (
        "hydra.launcher.gpus_per_node=0" in slam and "hydra.launcher.array_parallelism=16" in slam
    )


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            ["stages=[data,evaluate]"],
            "stages[1]: expected one of data, train, export, slam, tables, got 'evaluate'",
        ),
        (["data.kind=cloud"], "data.kind: expected one of 'synthetic', 'real', got 'cloud'"),
        (
            ["launcher.name=ray"],
            "launcher.name: unknown value 'ray'; accepted: basic, joblib, submitit_local, "
            "submitit_slurm",
        ),
        (
            ["data.synthetic.eval_seed=1"],
            "data.synthetic.eval_seed: sequence walking_xyz would be rendered with seed 1, a "
            "training or validation seed (0, 1, 2, 3, 4, 100, 101); choose another eval_seed",
        ),
        (
            ["data.synthetic.eval_size=640"],
            "data.synthetic.eval_size: size must be WIDTHxHEIGHT like 640x480, got '640'",
        ),
        (
            ["data.synthetic.source_outfits=plain"],
            "data.synthetic.source_outfits: expected one of 'classic', 'varied', 'all' or null, "
            "got 'plain'",
        ),
        (
            ["data.synthetic.shift=style"],
            "data.synthetic.shift: expected one of 'tum_like', 'appearance', 'full', got 'style'",
        ),
        (
            ["data.synthetic.source_outfits=varied"],
            "data.synthetic.source_outfits: varied is shift tum_like's to choose",
        ),
        (
            ["train.checkpoint=best"],
            "train.checkpoint: expected one of 'last', 'best_target_val', got 'best'",
        ),
        (
            ["scale=paper"],
            "data.real.voc: missing; data.kind=real needs the VOC folder (data.real.voc=PATH)",
        ),
        (
            ["sequences=[walking_xyz,kitchen]"],
            "sequences[1]: expected one of walking_xyz, walking_static, walking_rpy, ",
        ),
        (
            ["sequences=[sitting_xyz]"],
            "sequences: unknown value 'sitting_xyz'; accepted: walking_xyz, walking_static, ",
        ),
        (
            ["train.experiment=nope"],
            "train.experiment: expected one of 'ci', 'demo', 'demo_scratch', 'pretrain', "
            "'uss_slam_paper', got 'nope'",
        ),
        (
            ["systems=[harness,orbslam2]"],
            "systems[1]: expected one of harness, orbslam3, got 'orbslam2'",
        ),
        (
            ["grid.depth_sweep=[self_training]"],
            "grid.depth_sweep[0]: expected one of adaptsegnet, advent, got 'self_training'",
        ),
        (
            ["crf_params.iterations=0"],
            "crf_params.iterations must be a whole number >= 1, got 0",
        ),
        (
            ["+crf_params.sigma=3"],
            "crf_params.sigma: unknown key; expected one of iterations, gaussian_sxy, "
            "gaussian_compat, bilateral_sxy, bilateral_srgb, bilateral_compat",
        ),
        (
            ["+bogus=1"],
            "bogus: unknown key; expected one of scale_name, out_dir, stages, dry_run, ",
        ),
        (
            ["init.kind=pretrained", "init.seeds=[0,0]"],
            "init.seeds: expected a non-empty list of integers >= 0 and <= 4294967295, each once (0 is listed twice)",
        ),
    ],
)
def test_bad_config_is_one_line(overrides: list[str], message: str) -> None:
    with pytest.raises(UssSlamError) as info:
        experiment.check(compose_experiments(*overrides))
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def _not_installed(monkeypatch: pytest.MonkeyPatch, package: str) -> None:
    """``importlib.util.find_spec`` finds no ``package`` (as if it were not installed)."""
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == package else find_spec(name, *a),
    )


def test_crf_variants_need_pydensecrf(monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = compose_experiments("variants=[none,semantic,semantic_crf]")
    _not_installed(monkeypatch, "pydensecrf")
    with pytest.raises(UssSlamError) as info:
        experiment.check(cfg)
    assert str(info.value) == (
        "variants: semantic_crf needs pydensecrf (pip install 'uss-slam[crf]' (pydensecrf2))"
    )
    experiment.check(compose_experiments("variants=[none,semantic]"))  # no CRF: not needed


def test_orbslam3_needs_its_bindings_and_a_vocabulary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import importlib.util

    cfg = compose_experiments(
        "systems=[harness,orbslam3]", f"slam.orbslam3.vocabulary={tmp_path / 'missing.txt'}"
    )
    if importlib.util.find_spec("pyorbslam3") is not None:
        with pytest.raises(UssSlamError) as info:
            experiment.check(cfg)
        assert str(info.value).startswith(
            f"slam.orbslam3.vocabulary: system.vocabulary={tmp_path / 'missing.txt'}: file not found"
        )
    _not_installed(monkeypatch, "pyorbslam3")
    with pytest.raises(UssSlamError) as info:
        experiment.check(cfg)
    assert str(info.value) == (
        "systems: orbslam3 needs the pyorbslam3 package (pip install "
        "'uss-slam[orbslam3]'); without it accepted: harness"
    )


def test_missing_synthetic_data_names_the_folder(tmp_path: Path) -> None:
    exp = experiment.check(compose_experiments(f"out_dir={tmp_path}", "stages=[train]"))
    with pytest.raises(DataFormatError) as info:
        data.stage_data(exp, run=False)
    assert str(info.value).startswith(f"{tmp_path / 'data' / 'train'}: missing or incomplete")


def test_incomplete_real_data_names_the_folder(tmp_path: Path) -> None:
    (tmp_path / "voc").mkdir()
    overrides = [
        "scale=paper",
        f"data.real.voc={tmp_path / 'voc'}",
        f"data.real.sbd={tmp_path}",
        f"data.real.coco={tmp_path}",
        f"data.real.tum={tmp_path}",
        "init.kind=scratch",  # (scale=paper's warm start needs an init file)
    ]
    exp = experiment.check(compose_experiments(*overrides))
    with pytest.raises(DataFormatError) as info:
        data.stage_data(exp, run=False)
    assert str(info.value).startswith(f"{tmp_path / 'voc'}: not a VOC tree")


def test_missing_launcher_key_is_named_before_launching(tmp_path: Path) -> None:
    exp = experiment.check(compose_experiments("launcher=slurm", f"out_dir={tmp_path}"))
    assert exp.missing_launcher_keys == ["launcher.params.partition"]
    job = plan.Job("train/x", {"kind": "train", "key": {}, "overrides": []}, {})
    with pytest.raises(UssSlamError) as info:
        launch.launch(exp, "train", [job], set())
    assert str(info.value) == (
        "launcher.params.partition: missing; launcher=submitit_slurm "
        "needs it (launcher.params.partition=VALUE)"
    )


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (
            ["scale=huge"],
            "uss-experiments: error: scale: unknown value 'huge'; accepted: converged, paper, quick, standard, standard_full",
        ),
        (
            ["launcher=ray"],
            "uss-experiments: error: launcher: unknown value 'ray'; accepted: "
            "joblib, local, slurm, submitit_local",
        ),
        (
            ["grid.methods=[source_only,dann]"],
            "uss-experiments: error: grid.methods[1]: expected one of "
            f"{', '.join(method_names())}, got 'dann'",
        ),
        (
            ["train.experiment=nope"],
            "uss-experiments: error: train.experiment: expected one of 'ci', 'demo', "
            "'demo_scratch', 'pretrain', 'uss_slam_paper', got 'nope'",
        ),
        (
            ["systems=[harness,orbslam2]"],
            "uss-experiments: error: systems[1]: expected one of harness, orbslam3, got 'orbslam2'",
        ),
        (
            ["variants=[none,flow]"],
            "uss-experiments: error: variants[1]: expected one of none, geometry, semantic, "
            "semantic_crf, semantic_geometry, semantic_geometry_crf, semantic_geometry_object, "
            "oracle, got 'flow'",
        ),
    ],
)
def test_console_script_bad_input_one_line_no_work(
    tmp_path: Path, args: list[str], line: str, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    out = tmp_path / "out"
    monkeypatch.chdir(tmp_path)
    proc = _in_process([f"out_dir={out}", *args], monkeypatch, capsys)
    assert proc.returncode == 1
    assert proc.stderr.strip() == line
    assert not (out / "data").exists() and not (out / "train").exists()


def _in_process(
    argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys
) -> subprocess.CompletedProcess[str]:
    """``uss-experiments ARGV`` run in this process (as the CLI matrix runs it): one interpreter
    start-up less per case; ``test_a_bad_count_stops_a_dry_run_before_any_output`` starts the
    console script itself."""
    from test_cli_matrix import run_console_script

    try:
        code, out, err = run_console_script("uss-experiments", argv, monkeypatch, capsys)
    finally:
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    return subprocess.CompletedProcess(["uss-experiments", *argv], code, out, err)


def test_paper_scale_composes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    proc = _in_process(["scale=paper", "--cfg", "job"], monkeypatch, capsys)
    assert proc.returncode == 0, proc.stderr
    assert "experiment: uss_slam_paper" in proc.stdout and "kind: real" in proc.stdout
    assert "scale_name: paper" in proc.stdout


def test_dry_run_prints_the_plan_without_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    proc = _in_process(
        [f"out_dir={tmp_path}", "dry_run=true", "grid.seeds=[0]"], monkeypatch, capsys
    )
    assert proc.returncode == 0, proc.stderr
    # source-only, AdaptSegNet n = 4..7 and T0's target oracle
    assert "train: 6 jobs, 0 complete, 6 to run" in proc.stdout
    assert "  to run: train/adaptsegnet_n7_s0" in proc.stdout
    assert "  to run: train/oracle_s0" in proc.stdout
    # the 6 trainings' exports and the AdaBN one of source-only
    assert "export: 7 models, 0 complete, 7 to export" in proc.stdout
    assert "  to export: exports/adabn_s0 (AdaBN: train/source_only_s0's checkpoint" in proc.stdout
    # 7 segmentation evaluations (6 trainings + AdaBN), 4 on the source val split (T0's rows:
    # source-only, AdaptSegNet n = 5, oracle, AdaBN) + 2 sequences x (3 model-free + 7 semantic
    # + 2 x 2 geometry + AdaBN's semantic+geometry)
    assert "slam: 41 jobs, 0 complete, 6 to run, 35 blocked until their model exists" in proc.stdout
    assert (
        "  after exports/adabn_s0: segeval/adabn_s0, segeval/source_val/adabn_s0, "
        "slam/harness/walking_xyz/semantic/adabn_s0, "
        "slam/harness/walking_xyz/semantic_geometry/adabn_s0, "
        "slam/harness/static_xyz/semantic/adabn_s0, "
        "slam/harness/static_xyz/semantic_geometry/adabn_s0\n"
    ) in proc.stdout
    assert not (tmp_path / "data").exists() and not (tmp_path / "train").exists()


def test_a_dry_run_with_stdout_closed_is_its_one_line(tmp_path: Path) -> None:
    """The plan is a dry run's product: with stdout closed (``>&-``) its error is the one
    line, before the configs' checks (whose warnings, for a setting another method takes,
    came first)."""
    import os

    argv = [str(Path(sys.executable).parent / "uss-experiments"), f"out_dir={tmp_path}/x",
            "dry_run=true"]  # fmt: skip
    done = subprocess.run(argv, cwd=tmp_path, capture_output=False, stderr=subprocess.PIPE,
                          text=True, timeout=600, preexec_fn=lambda: os.close(1))  # fmt: skip
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        "uss-experiments: error: stdout is closed (>&-): the output cannot be written"
    ]
    assert not (tmp_path / "x").exists()


def _tiny_onnx(path: Path) -> Path:
    """tests/slam_eval's tiny exported segmenter (logits from the pixel colours)."""
    import importlib.util

    source = (
        Path(__file__).resolve().parents[1] / "slam_eval" / "segmenters" / "test_onnx_segmenter.py"
    )
    spec = importlib.util.spec_from_file_location("onnx_segmenter_tests", source)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.tiny_model(path, module._metadata(), bias=150.0)


def test_segeval_with_the_crf_uses_the_slam_runtime_crf(
    tmp_path: Path, synthetic_sequence: Callable[..., Path]
) -> None:
    pytest.importorskip("pydensecrf")
    from uss_slam.core.classes import CLASS_NAMES
    from uss_slam.core.seg_metrics import iou_report
    from uss_slam.pipelines.evaluate import evaluate_frames, sequence_frames
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    seq = synthetic_sequence(preset="walking_xyz", frames=6, size=(96, 72))
    model = _tiny_onnx(tmp_path / "m.onnx")
    spec = {"model": str(model), "sequences": {"walking_xyz": str(seq)}, "stride": 2}
    plain = jobs.run_segeval(tmp_path / "plain", spec)
    crf = jobs.run_segeval(tmp_path / "crf", {**spec, "crf": {"iterations": 2}})
    assert "crf" not in plain["model"] and crf["model"]["crf"] == {"iterations": 2}
    assert crf["sequences"]["all"]["frames"] == plain["sequences"]["all"]["frames"] == 3
    # the same CRF as uss-slam segmenter=onnx segmenter.crf=true segmenter.crf_params.iterations=2
    runtime = OnnxSegmenter(model, threads=1, crf=True, crf_params={"iterations": 2})
    frames = sequence_frames([seq], 2).frames()
    expected = iou_report(evaluate_frames(runtime.infer, frames, CLASS_NAMES).matrix, CLASS_NAMES)
    assert crf["sequences"]["walking_xyz"]["mIoU"] == expected["mIoU"]
    assert crf["sequences"]["walking_xyz"]["mIoU"] != plain["sequences"]["walking_xyz"]["mIoU"]


def test_appearance_shift_trains_on_image_folders_and_plans_no_slam(tmp_path: Path) -> None:
    """The appearance shift's target is labelled images: the trainings point data=synthetic at
    its image folders, the evaluation renders image folders, and no SLAM job is planned."""
    exp = experiment.check(
        compose_experiments(f"out_dir={tmp_path}", "data.synthetic.shift=appearance")
    )
    train_dir = tmp_path / "data" / "train"
    found = data.Data(train_dir=train_dir)
    overrides, _ = plan.train_overrides(exp, found, exp.grid.trainings[0])
    roots = [o for o in overrides if o.startswith("data.target.roots=")]
    assert roots == [
        "data.target.roots=[" + ",".join(
            str(train_dir / f"target_train/images_{k}") for k in range(4)) + "]"
    ]  # fmt: skip
    stage = data.sequence_stage(exp, exp.grid.sequences[0])
    assert stage.key["images"] is True and stage.key["outfits"] == "classic"
    for name in exp.grid.sequences:
        found.sequences[name] = tmp_path / name
        found.sequence_keys[name] = {"preset": name}
        found.labelled.append(name)
    kinds = {job.spec["kind"] for job in plan.plan_slam(exp, found, {})}
    assert kinds == {"segeval"}
    tum_like = experiment.check(compose_experiments(f"out_dir={tmp_path}"))
    assert data.sequence_stage(tum_like, "walking_xyz").key["outfits"] == "drawn"
    assert {job.spec["kind"] for job in plan.plan_slam(tum_like, found, {})} == {"segeval", "slam"}


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("segeval.stride=0", "segeval.stride: expected an integer >= 1, got 0"),
        ("segeval.stride=1.5", "segeval.stride: expected an integer >= 1, got 1.5"),
        (
            "segeval.threads=0",
            f"segeval.threads: expected an integer >= 1 and <= {MAX_THREADS} or null, got 0",
        ),
        ("segeval.source_val_stride=-1", "segeval.source_val_stride: expected an integer >= 1"),
        ("data.synthetic.eval_frames=1", "data.synthetic.eval_frames: expected an integer >= 2"),
        ("data.synthetic.train_frames=x", "data.synthetic.train_frames: expected an integer"),
        ("data.synthetic.voc_images=0", "data.synthetic.voc_images: expected an integer >= 1"),
        (
            "data.synthetic.eval_frames=4 segeval.stride=5",
            "eval_frames: 4 frames hold no frame for segeval.stride=5",
        ),
    ],
)
def test_counts_the_jobs_read_late_are_checked_first(override: str, message: str) -> None:
    with pytest.raises(UssSlamError, match=message.replace(".", r"\.").replace("(", r"\(")):
        experiment.check(compose_experiments(*override.split()))


def test_a_bad_count_stops_a_dry_run_before_any_output(tmp_path: Path) -> None:
    out = tmp_path / "exp"
    done = subprocess.run(
        [*PROG, f"out_dir={out}", "dry_run=true", "segeval.stride=0"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        "uss-experiments: error: segeval.stride: expected an integer >= 1, got 0"
    ]
    assert not (out / "train").exists() and not (out / "data").exists()  # no work started


def _train_plan(tmp_path: Path, overrides: list[str], key: str = "k") -> Path:
    """A plan of one training job (``train/a``, cache key ``key``) as uss-experiments writes it."""
    spec = {"kind": "train", "key": {"k": key}, "overrides": overrides}
    plan_file = tmp_path / "jobs" / "train.json"
    write_json_atomic(
        plan_file, {"stage": "train", "out": str(tmp_path), "cells": {"train/a": spec}}
    )
    return plan_file


def test_an_interrupted_training_goes_on_from_its_last_checkpoint(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    """A training job stopped half-way (Ctrl-C, a kill, a pre-empted SLURM job) keeps its
    checkpoints; the next run of the same key goes on from ``last.ckpt``, not from scratch. One
    of another key, or after a run that failed, starts afresh."""
    import torch
    from shared_helpers import data_overrides

    def iteration(where: Path | None = None) -> int:
        ckpt = (where or folder) / "checkpoints" / "last.ckpt"
        return torch.load(ckpt, weights_only=True)["iteration"]

    common = [
        "experiment=ci",
        *data_overrides(uda_data),
        "logger=none",
        "+trainer.limit_val_batches=1",
    ]
    # stands in for the interruption (not part of the job's key)
    stop = ["+callbacks.stop._target_=pipeline_helpers.interrupt_at", "+callbacks.stop.iteration=2"]
    folder = tmp_path / "train" / "a"
    with pytest.raises(KeyboardInterrupt):
        jobs.run_cell(_train_plan(tmp_path, [*common, *stop]), tmp_path, "train/a")
    assert iteration() == 2 and not (folder / jobs.RESULT).exists()

    plan_file = _train_plan(tmp_path, common)
    assert jobs.run_cell(plan_file, tmp_path, "train/a")["status"] == "ok"
    result = json.loads((folder / jobs.RESULT).read_text())
    assert result["resumed_from_iteration"] == 2 and iteration() == 4
    assert result["checkpoint"] == "checkpoints/last.ckpt"
    assert jobs.run_cell(plan_file, tmp_path, "train/a") == {"status": "reused"}

    # interrupted, then a run of another key: from scratch
    with pytest.raises(KeyboardInterrupt):
        jobs.run_cell(_train_plan(tmp_path, [*common, *stop], "b"), tmp_path, "train/a")
    assert jobs.run_cell(_train_plan(tmp_path, common, "c"), tmp_path, "train/a")["status"] == "ok"
    assert "resumed_from_iteration" not in json.loads((folder / jobs.RESULT).read_text())

    # interrupted, then a run of the same key that fails: the next one starts afresh; all the
    # while the finished result of key "c" stays (the reruns work in the staging folder)
    staging = folder.with_name(".a.next")
    with pytest.raises(KeyboardInterrupt):
        jobs.run_cell(_train_plan(tmp_path, [*common, *stop], "d"), tmp_path, "train/a")
    assert iteration(staging) == 2 and iteration() == 4
    bad = _train_plan(tmp_path, [*common, "model.optimizer.lr=-1"], "d")
    assert jobs.run_cell(bad, tmp_path, "train/a")["status"] == "failed"
    assert iteration(staging) == 2  # a failed run leaves the checkpoints it found
    assert (folder / jobs.FAILURE).is_file() and (folder / jobs.RESULT).is_file()
    assert jobs.run_cell(_train_plan(tmp_path, common, "d"), tmp_path, "train/a")["status"] == "ok"
    assert not staging.exists() and not (folder / jobs.FAILURE).exists()
    assert "resumed_from_iteration" not in json.loads((folder / jobs.RESULT).read_text())
    assert iteration() == 4


def test_the_plan_names_a_training_that_goes_on(tmp_path: Path) -> None:
    """The dry run's plan says which trainings go on from an interrupted run's checkpoint."""
    exp = experiment.check(compose_experiments(f"out_dir={tmp_path}", "grid.seeds=[0]"))
    jobs_ = plan.plan_train(exp, data.Data(train_dir=tmp_path / "data" / "train"))
    first = jobs.stage_of(exp.out, jobs_[0].spec, jobs_[0].id)
    first.start()  # started, then killed after its first checkpoint
    (first.folder / "checkpoints").mkdir()
    (first.folder / "checkpoints" / "last.ckpt").write_bytes(b"x")
    lines = launch.describe_plan(exp, "train", jobs_, set()).splitlines()
    resumed = f"  to run: {jobs_[0].id} (goes on from its interrupted run's checkpoints/last.ckpt)"
    assert resumed in lines
    assert f"  to run: {jobs_[1].id}" in lines  # not started: from scratch


def test_segeval_keeps_each_sequences_confusion_matrix(
    tmp_path: Path, synthetic_sequence: Callable[..., Path]
) -> None:
    """Each sequence's confusion matrix is in the result: their sum gives the pooled figures,
    so a subset (the walking sequences without the static control) can be pooled later."""
    import numpy as np

    from uss_slam.core.classes import CLASS_NAMES
    from uss_slam.core.seg_metrics import iou_report

    walking = synthetic_sequence(preset="walking_xyz", frames=4, size=(96, 72), seed=1)
    static = synthetic_sequence(preset="static_xyz", frames=4, size=(96, 72), seed=2)
    model = _tiny_onnx(tmp_path / "m.onnx")
    spec = {"model": str(model), "sequences": {"w": str(walking), "s": str(static)}, "stride": 2}
    scores = jobs.run_segeval(tmp_path / "job", spec)["sequences"]
    for name in ("w", "s"):
        matrix = np.array(scores[name]["confusion"])
        assert matrix.shape == (len(CLASS_NAMES), len(CLASS_NAMES))
        assert matrix.sum() == 2 * 96 * 72  # every pixel of the 2 evaluated frames, once
        assert iou_report(matrix, CLASS_NAMES)["mIoU"] == scores[name]["mIoU"]
    pooled = np.array(scores["w"]["confusion"]) + np.array(scores["s"]["confusion"])
    assert iou_report(pooled, CLASS_NAMES)["mIoU"] == scores["all"]["mIoU"]

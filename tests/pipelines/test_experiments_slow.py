"""uss-experiments end to end (slow): scale=quick as CI runs it (its warm start included), a
rerun that reuses every job, an interrupted run resumed, a failing job marked while the others go
on (through submitit's local executor, the SLURM launcher's path), and the paper scale's
one-iteration fast_dev_run on files in the real data formats.

scale=quick runs once per module (the ``quick`` fixture, from an empty folder); the other tests
start from copies of its data (training renders, pretraining set, pretrained init), and those
that are not about the trainings from copies of the trainings and exports they need: a moved
run's jobs are reused (their keys hold no absolute path), which the tests assert."""

from __future__ import annotations

import csv
import hashlib
import importlib.util
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from uss_slam.pipelines.runs import SlamJob
from uss_slam.synthetic import render_sequence

pytestmark = pytest.mark.slow
PROG = [sys.executable, "-m", "uss_slam.pipelines.experiments.cli"]
STAMP = ".uss-demo.json"


def run(out: Path, *overrides: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*PROG, f"out_dir={out}", *overrides], capture_output=True, text=True, cwd=cwd, timeout=1800
    )


def runs_csv(out: Path) -> list[dict[str, str]]:
    with (out / "runs.csv").open() as f:
        return list(csv.DictReader(f))


def pending(out: Path, stage: str) -> list[str]:
    return json.loads((out / "jobs" / f"{stage}.json").read_text())["pending"]


NO_T0 = ("grid.adabn=false", "grid.oracle=false", "segeval.source_val_stride=null")
"""T0's reference jobs off: the tests of other paths keep their grid (and runtime)."""


QuickRun = tuple[Path, subprocess.CompletedProcess[str]]


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> QuickRun:
    """``uss-experiments`` at scale=quick from an empty folder, as CI runs it: the run folder and
    the call's output. Read-only: tests copy what they change or rerun."""
    root = tmp_path_factory.mktemp("quick")
    out = root / "quick"
    first = run(out, cwd=root)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    return out, first


def copy_of(quick_out: Path, out: Path, *parts: str) -> Path:
    """``out`` holding copies of the quick run's ``parts`` (``data``, ``train/source_only_s0``,
    ...): what a later run with the same keys reuses."""
    for part in parts:
        shutil.copytree(quick_out / part, out / part, symlinks=True)
    return out


def test_quick_end_to_end_then_reuse_then_resume(quick: QuickRun, tmp_path: Path) -> None:
    source, first = quick
    rows = runs_csv(source)
    kinds = [r["kind"] for r in rows]
    # 12 trainings (source-only + n = 4..7 + T0's oracle, 2 seeds), their exports and AdaBN's
    # of source-only, the 14 models' segmentation metrics (2 sequences + pooled) and T0's 4 x 2
    # on the source val split, 2 x (3 model-free + 14 semantic + 4 x 2 geometry + AdaBN's 2
    # semantic+geometry) SLAM runs
    assert (
        kinds.count("train"),
        kinds.count("export"),
        kinds.count("segeval"),
        kinds.count("slam"),
    ) == (12, 14, 14 * 3 + 8, 54)
    assert {r["status"] for r in rows} == {"ok"}
    slam_rows = [r for r in rows if r["kind"] == "slam"]
    # A quick-scale model learns next to nothing: one whose masks cover every frame leaves no
    # keypoint to track, recorded as tracked_fraction 0 without an ATE; the rest have one.
    assert all(r["ate_rmse"] or float(r["tracked_fraction"]) == 0.0 for r in slam_rows)
    assert all(r["ate_rmse"] for r in slam_rows if r["variant"] in ("none", "oracle"))
    md = (source / "tables.md").read_text()
    for title in (
        "### T0: the UDA table",
        "#### T0 per seed",
        "#### T0 person masks and SLAM",
        "### T1a",
        "### T1b",
        "### T2: without ATL (source_only) vs with ATL (adaptsegnet_n5)",
        "### T2 summary",
        "### T3",
        "### Baselines",
        "### Downstream ratio",
        "### Failures",
    ):
        assert title in md
    assert "Every job succeeded." in md
    tables = json.loads((source / "tables.json").read_text())
    seg = {r["config"]: r["mIoU"] for r in tables["T1"]["segmentation"]}
    assert list(seg) == ["source_only", *(f"adaptsegnet_n{n}" for n in (4, 5, 6, 7))]
    assert all(s["n"] == 2 and s["failed"] == 0 for s in seg.values())
    t0 = {r["config"]: r for r in tables["T0"]["rows"]}
    assert list(t0) == ["source_only", "adabn", "adaptsegnet_n5", "oracle"]
    for row in t0.values():  # every cell holds both seeds
        assert row["source_val_mIoU"]["n"] == row["mIoU"]["n"] == 2
        assert set(row["mIoU"]["per_seed"]) == {"0", "1"}
    assert t0["oracle"]["target_labels"] == "training" and "| oracle † | training |" in md
    assert "- T0: AdaBN on 48 evenly spaced target training frames; oracle trained" in md
    for name in ("t1_miou.png", "t1_iou_per_class.png", "ate_per_sequence.png"):
        assert (source / "plots" / name).stat().st_size > 0
    for sequence in ("walking_xyz", "static_xyz"):  # held-out seeds 1000 + preset index
        record = json.loads((source / "data" / "eval" / sequence / STAMP).read_text())
        assert record["seed"] not in (0, 1, 2, 3, 4, 100)

    # the tables alone, again: runs.csv keeps every row (the exports' too)
    out = tmp_path / "quick"
    shutil.copytree(source, out, symlinks=True)
    tables_only = run(out, "stages=[tables]", cwd=tmp_path)
    assert tables_only.returncode == 0, tables_only.stderr[-3000:]
    assert sorted(r["id"] for r in runs_csv(out)) == sorted(r["id"] for r in rows)

    again = run(out, cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "train: 12 training jobs: every job complete already (reused)" in again.stdout
    assert "export: last checkpoints -> ONNX: 0 exported, 14 reused" in again.stdout
    assert "every job complete already (reused)" in again.stdout.split("slam:")[-1]
    assert pending(out, "train") == [] and pending(out, "slam") == []

    # An interrupted run: one training and one SLAM run left no stamp (a killed job never
    # writes it). The rerun redoes exactly those, and what depends on the retrained model only
    # if its export changed.
    (out / "train" / "adaptsegnet_n6_s1" / STAMP).unlink()
    killed_slam = "slam/harness/walking_xyz/semantic/source_only_s0"
    (out / killed_slam / STAMP).unlink()
    resumed = run(out, cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert pending(out, "train") == ["train/adaptsegnet_n6_s1"]
    redone = pending(out, "slam")
    assert killed_slam in redone
    assert all(j == killed_slam or j.endswith("/adaptsegnet_n6_s1") for j in redone), redone
    assert {r["status"] for r in runs_csv(out)} == {"ok"}

    # More methods on the finished run: every job of it is complete in the new plan; only the
    # new methods' trainings (at tables.n_layers) and their jobs are to run.
    more = run(out, "dry_run=true", f"grid.methods=[{','.join(ALL_METHODS)}]", cwd=tmp_path)
    assert more.returncode == 0, more.stderr[-3000:]
    assert "train: 18 jobs, 12 complete, 6 to run" in more.stdout
    planned = [line.split(": ", 1)[1] for line in more.stdout.splitlines() if "  to run: " in line]
    assert {p for p in planned if p.startswith("train/")} == {
        f"train/{c}_s{s}" for c in ("advent_n5", "minent", "self_training") for s in (0, 1)
    }
    # 6 segmentation evaluations (and 6 on the source val split: T0 rows) + 2 sequences x 6
    # semantic runs, blocked until exported
    assert "slam: 100 jobs, 76 complete, 0 to run, 24 blocked until their model exists" in (
        more.stdout
    )
    assert "pretraining set reused, pretrained init i0: reused" in more.stdout
    assert "init: 1 jobs, 1 complete, 0 to run" in more.stdout


def test_quick_scale_warm_starts_every_training(quick: QuickRun, tmp_path: Path) -> None:
    """The warm start of the quick run (the pretraining set, the init, every training from it);
    then the run's stages [data,train,tables] alone on copies of its data and trainings: every
    init and training reused, the tables from the trainings alone."""
    source, first = quick
    assert re.search(r"pretrained init i0: trained in \d+ (s|min)", first.stdout), first.stdout
    init = source / "data" / "init" / "i0" / "init.ckpt"
    result = json.loads((source / "data" / "init" / "i0" / "result.json").read_text())
    assert result["init_sha256"] == hashlib.sha256(init.read_bytes()).hexdigest()
    trainings = sorted(p.name for p in (source / "train").iterdir())
    assert trainings == sorted(
        [f"{c}_s{s}" for c in ("source_only", "oracle") for s in (0, 1)]
        + [f"adaptsegnet_n{n}_s{s}" for n in (4, 5, 6, 7) for s in (0, 1)]
    )
    for name in trainings:  # the weights loader names the file each training read
        log = (source / "logs" / "train" / f"{name}.log").read_text()
        assert f"{init}: read as checkpoint weights" in log, name
        stamp = json.loads((source / "train" / name / STAMP).read_text())
        assert stamp["init"] == result["init_sha256"]
    header = "- init: pretrained, every training from the init of its init seed (i0)"
    assert header in (source / "tables.md").read_text()

    out = copy_of(source, tmp_path / "warm", "data", "train")
    grid = ("grid.n_layers=[5]", "sequences=[walking_xyz]")
    done = run(out, *grid, "stages=[data,train,tables]", cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "pretraining set reused, pretrained init i0: reused" in done.stdout
    assert "train: 6 training jobs: every job complete already (reused)" in done.stdout
    assert header in (out / "tables.md").read_text()
    again = run(out, *grid, "dry_run=true", cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "pretraining set reused, pretrained init i0: reused" in again.stdout
    assert "init: 1 jobs, 1 complete, 0 to run" in again.stdout
    assert "train: 6 jobs, 6 complete, 0 to run" in again.stdout


ALL_METHODS = ("source_only", "adaptsegnet", "advent", "minent", "self_training")


def test_more_methods_and_the_crf_reuse_a_finished_run(quick: QuickRun, tmp_path: Path) -> None:
    pytest.importorskip("pydensecrf")
    models = ("source_only_s0", "adaptsegnet_n4_s0", "adaptsegnet_n5_s0")
    parts = [f"{folder}/{m}" for folder in ("train", "exports") for m in models]
    out = copy_of(quick[0], tmp_path / "crf", "data", *parts)
    grid = [
        "grid.seeds=[0]",
        "grid.n_layers=[4,5]",
        "sequences=[walking_xyz]",
        "data.synthetic.eval_frames=12",
        *NO_T0,
    ]
    first = run(out, *grid, "variants=[none,semantic,semantic_geometry,oracle]", cwd=tmp_path)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    assert "train: 3 training jobs: every job complete already (reused)" in first.stdout
    assert "export: last checkpoints -> ONNX: 0 exported, 3 reused" in first.stdout
    done = {r["id"] for r in runs_csv(out)}
    assert len(done) == 3 + 3 + 3 + (2 + 3 + 2)  # trainings, exports, segeval, SLAM runs

    variants = (
        "variants=[none,semantic,semantic_crf,semantic_geometry,semantic_geometry_crf,oracle]"
    )
    methods = f"grid.methods=[{','.join(ALL_METHODS)}]"
    more = run(out, *grid, methods, variants, cwd=tmp_path)
    assert more.returncode == 0, more.stdout[-3000:] + more.stderr[-3000:]
    # every finished job reused: only the new methods' trainings and the new jobs ran
    assert pending(out, "train") == [
        "train/advent_n5_s0",
        "train/minent_s0",
        "train/self_training_s0",
    ]
    ran = set(pending(out, "slam"))
    assert not ran & done
    crf = {
        "segeval/crf/source_only_s0",
        "segeval/crf/adaptsegnet_n5_s0",
        *(
            f"slam/harness/walking_xyz/{v}/{m}"
            for v in ("semantic_crf", "semantic_geometry_crf")
            for m in ("source_only_s0", "adaptsegnet_n5_s0")
        ),
    }
    new_methods = {
        f"{kind}/{m}"
        for kind in ("segeval", "slam/harness/walking_xyz/semantic")
        for m in ("advent_n5_s0", "minent_s0", "self_training_s0")
    }
    assert ran == crf | new_methods
    rows = runs_csv(out)
    assert {r["status"] for r in rows} == {"ok"}
    slam = {r["id"]: r for r in rows if r["kind"] == "slam"}
    for run_id, row in slam.items():
        with_crf = "_crf/" in run_id
        assert row["crf"] == str(int(with_crf))
        assert bool(row["crf_ms"]) == with_crf, run_id  # the CRF's time, in its runs only
        if with_crf:
            assert 0 < float(row["crf_ms"]) <= float(row["segmentation_ms"])
        assert float(row["total_ms"]) > 0
    seg_crf = [r for r in rows if r["id"] == "segeval/crf/adaptsegnet_n5_s0"]
    assert [r["sequence"] for r in seg_crf] == ["walking_xyz", "all"]
    assert all(r["crf"] == "1" and r["mIoU"] for r in seg_crf)
    md = (out / "tables.md").read_text()
    for title in (
        "### T2 by method: adapted vs source-only",
        "### Dense CRF off / on (harness)",
        "### Time per frame (harness)",
    ):
        assert title in md
    tables = json.loads((out / "tables.json").read_text())
    assert [r["config"] for r in tables["T2"]["by_method"]] == [
        "source_only",
        "adaptsegnet_n5",
        "advent_n5",
        "minent",
        "self_training",
    ]
    assert tables["T2"]["by_method"][0]["mIoU_vs_source_only_points"] == 0.0
    crf_rows = [(r["config"], r["filter"], r["crf"]) for r in tables["crf"]]
    assert crf_rows == [
        (c, f, on)
        for c in ("source_only", "adaptsegnet_n5")
        for f in ("semantic", "semantic_geometry")
        for on in (False, True)
    ]
    assert all(r["ate_rmse"]["walking_xyz"]["n"] == 1 for r in tables["crf"])
    timing = {r["variant"]: r for r in tables["timing"]}
    assert timing["semantic_crf"]["crf_ms"]["n"] == 2  # the two compared models
    assert timing["semantic"]["crf_ms"]["n"] == 0


def test_submitit_local_refuses_an_impossible_depth_before_any_job(
    quick: QuickRun, tmp_path: Path
) -> None:
    """An 8-layer discriminator on 129-pixel crops is refused for the whole grid before any job
    is submitted (it used to fail as a training job); without it every job runs through
    submitit (the data and init are the quick run's)."""
    out = copy_of(quick[0], tmp_path / "sub", "data")
    grid = [
        "launcher=submitit_local",
        "grid.seeds=[0]",
        "grid.n_layers=[4,8]",
        "sequences=[static_xyz]",
        "variants=[none,semantic,oracle]",
        "tables.n_layers=4",
        "data.synthetic.eval_frames=12",
        *NO_T0,
    ]
    first = run(out, *grid, cwd=tmp_path)
    assert first.returncode == 1
    lines = first.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("uss-experiments: error: ")
    assert "n_layers" in lines[0] and not (out / ".submitit").exists()

    fixed = run(out, *[g.replace("[4,8]", "[4]") for g in grid], cwd=tmp_path)
    assert fixed.returncode == 0, fixed.stderr[-3000:]
    assert "train: 2 training jobs: ran 2 jobs (multirun exit code 0)" in fixed.stdout
    assert (out / ".submitit").is_dir()  # the jobs went through submitit
    status = {r["id"]: r["status"] for r in runs_csv(out)}
    assert status["train/source_only_s0"] == status["train/adaptsegnet_n4_s0"] == "ok"
    assert status["slam/harness/static_xyz/semantic/adaptsegnet_n4_s0"] == "ok"


def test_joblib_runs_jobs_in_parallel_processes(quick: QuickRun, tmp_path: Path) -> None:
    """The trainings and SLAM runs through joblib (the data and init are the quick run's)."""
    out = copy_of(quick[0], tmp_path / "joblib", "data")
    done = run(
        out,
        "launcher=joblib",
        "launcher.params.n_jobs=2",
        "grid.methods=[source_only]",
        "grid.seeds=[0,1]",
        "sequences=[static_xyz]",
        "variants=[none,semantic]",
        "data.synthetic.eval_frames=12",
        *NO_T0,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    log = (out / "logs" / "train.multirun.log").read_text()
    assert "hydra/launcher=joblib" in log and "Joblib.Parallel(n_jobs=2," in log
    rows = runs_csv(out)
    assert len(rows) == 2 + 2 + 2 * 2 + 3 and {r["status"] for r in rows} == {"ok"}


def _realdata_helpers():
    """tests/datasets/realdata_helpers.py (the writers of files in the real formats)."""
    if "realdata_helpers" in sys.modules:  # imported by the dataset tests of this session
        return sys.modules["realdata_helpers"]
    path = Path(__file__).resolve().parents[1] / "datasets" / "realdata_helpers.py"
    spec = importlib.util.spec_from_file_location("realdata_helpers", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["realdata_helpers"] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_paper_scale_fast_dev_run_on_real_formats(tmp_path: Path) -> None:
    helpers = _realdata_helpers()
    shape = (40, 48)
    scenes = helpers.standard_scenes(shape)
    labels = {name: helpers.paint_voc(shape, scene) for name, scene in scenes.items()}
    names = list(labels)
    voc = helpers.write_voc(tmp_path / "voc", labels, {"trainval": names, "val": names[3:]})
    sbd_labels = {n.replace("2008", "2009"): label for n, label in labels.items()}
    helpers.write_sbd(tmp_path / "sbd", sbd_labels, {"train": list(sbd_labels)})
    coco = helpers.write_coco(
        tmp_path / "coco",
        {k + 1: (f"{n}.jpg", s) for k, (n, s) in enumerate(scenes.items())},
        shape,
    )
    tum = tmp_path / "tum"
    for name in ("walking_xyz", "sitting_static"):  # TUM's layout: no labels/
        folder = render_sequence(
            tum / f"rgbd_dataset_freiburg3_{name}", preset=name, frames=8, size=(96, 72), seed=7
        )
        shutil.rmtree(folder / "labels")
    out = tmp_path / "paper"
    overrides = [
        "scale=paper",
        "fast_dev_run=true",
        "stages=[data,train]",
        f"data.real.voc={voc}",
        f"data.real.sbd={tmp_path / 'sbd'}",
        f"data.real.coco={coco}",
        f"data.real.tum={tum}",
        "data.real.target=[walking_xyz,sitting_static]",
        "sequences=[walking_xyz]",
        "grid.seeds=[0]",
        "grid.n_layers=[5]",
        "init.kind=scratch",  # (scale=paper's warm start needs the COCO init file)
        # on this CPU machine, offline: no ImageNet download, small crops, no GPU
        'train.overrides=["model.net.backbone_weights=null","model.net.allow_random_init=true",'
        '"trainer=cpu","logger=none",'
        '"data.source.transform.crop_size=65","data.target.transform.crop_size=65"]',
    ]
    dry = run(out, *overrides, "dry_run=true", cwd=tmp_path)
    assert dry.returncode == 0, dry.stderr[-3000:]
    assert (
        "real data checked: VOC, SBD, COCO, 2 target and 1 evaluation sequences (0 labelled)"
        in dry.stdout
    )
    assert "train: 2 jobs, 0 complete, 2 to run" in dry.stdout
    done = run(out, *overrides, cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    for model in ("source_only_s0", "adaptsegnet_n5_s0"):
        folder = out / "train" / model
        # the key holds each target folder's path and the fingerprint of its files
        target = json.loads((folder / STAMP).read_text())["data"]["target"]
        assert [t.rsplit(":", 1)[0] for t in target] == [
            str(tum / "rgbd_dataset_freiburg3_walking_xyz"),
            str(tum / "rgbd_dataset_freiburg3_sitting_static"),
        ]
        assert all(len(t.rsplit(":", 1)[1]) == 64 for t in target)
        config = (folder / ".hydra" / "config.yaml").read_text()
        assert "backbone: resnet101" in config and "max_iters: 1" in config
        assert list((folder / "checkpoints").glob("*.ckpt"))


def test_orbslam3_runs_next_to_the_harness(quick: QuickRun, tmp_path: Path) -> None:
    """ORB-SLAM3's jobs beside the harness's on the quick run's data, training and export."""
    pytest.importorskip("pyorbslam3")
    model = "source_only_s0"
    out = copy_of(quick[0], tmp_path / "orb", "data", f"train/{model}", f"exports/{model}")
    done = run(
        out,
        "grid.methods=[source_only]",
        "grid.seeds=[0]",
        "systems=[harness,orbslam3]",
        "sequences=[walking_xyz]",
        "variants=[none,semantic,geometry,oracle]",
        "slam.orbslam3.repeats=2",
        *NO_T0,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "train: 1 training jobs: every job complete already (reused)" in done.stdout
    rows = {r["id"]: r for r in runs_csv(out)}
    orb = {i for i in rows if i.startswith("slam/orbslam3/")}
    # the mask variants only: geometry is the harness's own check
    assert orb == {
        "slam/orbslam3/walking_xyz/none",
        "slam/orbslam3/walking_xyz/oracle",
        "slam/orbslam3/walking_xyz/semantic/source_only_s0",
    }
    assert all(rows[i]["status"] == "ok" and rows[i]["ate_rmse"] for i in orb)
    vocabulary = out / "data" / "orbslam3_vocabulary" / "vocabulary.txt"
    plan = json.loads((out / "jobs" / "slam.json").read_text())["cells"]
    overrides = SlamJob.from_json(plan["slam/orbslam3/walking_xyz/oracle"]["job"]).overrides()
    assert overrides[-4:] == [
        "filters=[]",
        "system=orbslam3",
        f"system.vocabulary={vocabulary}",
        "system.repeats=2",
    ]
    result = json.loads((out / "slam/orbslam3/walking_xyz/oracle/result.json").read_text())
    assert result["ate_rmse_repeats"]["evaluated"] == 2
    assert (
        "### Baselines: ATE RMSE [m] without a trained segmenter (orbslam3)"
        in (out / "tables.md").read_text()
    )

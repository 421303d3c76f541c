"""``uss-demo`` options and plan that need no training: ``--train-threads`` reaches both
trainings, both start from the packaged init, the SLAM rows repeat on a sequence of the demo's
own seed, ``--until``, and bad ``--sequence`` / ``--out`` values fail in one line before any
work."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines import demo, synthetic_data
from uss_slam.pipelines.assets import demo_init_path


def test_train_threads_override_only_when_given() -> None:
    plan = demo.PLANS["demo"]
    default = demo.train_overrides(plan, Path("/d"), "adapted")
    assert not any(o.startswith("num_threads=") for o in default)
    one = demo.train_overrides(plan, Path("/d"), "source_only", threads=1)
    assert one[: len(default)] == [
        "experiment=demo",
        "model/method=source_only",
        "paths.data_dir=/d",
        "run_name=demo_source_only",
        f"model.net.weights_path={demo_init_path()}",
    ]
    assert default[1] == "model/method=adaptsegnet"
    assert one[-1] == "num_threads=1"


def test_train_threads_option() -> None:
    parser = demo.build_parser()
    assert parser.parse_args([]).train_threads is None
    assert parser.parse_args(["--train-threads", "1"]).train_threads == 1
    with pytest.raises(UssSlamError, match="--train-threads: expected an integer >= 1 and <= "):
        demo.run_demo(Path("/nonexistent"), train_threads=0)


def test_until_option_and_step_counts() -> None:
    parser = demo.build_parser()
    assert parser.parse_args([]).until == "report"
    assert parser.parse_args(["--until", "data"]).until == "data"
    assert demo._steps("report") == 14 and demo._steps("data") == 1 and demo._steps("train") == 3
    assert demo._steps("export") == 6  # source-only, AdaBN, adapted
    with pytest.raises(UssSlamError, match="--until deploy: not a stage"):
        demo.run_demo(Path("/nonexistent"), until="deploy")


def _one_line_error(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exit_info:
        demo.main(argv)
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_sequence_folder_is_checked_before_any_work(
    tmp_path: Path, capsys, synthetic_sequence
) -> None:
    """A --sequence folder the SLAM, mIoU or report stage could not read fails at once."""
    out = tmp_path / "out"
    source = synthetic_sequence(frames=4, size=(64, 48))
    no_labels = tmp_path / "no_labels"
    shutil.copytree(source, no_labels)
    shutil.rmtree(no_labels / "labels")
    err = _one_line_error(["--out", str(out), "--experiment", "ci", "--sequence",
                           str(no_labels)], capsys)  # fmt: skip
    assert err.startswith(f"uss-demo: error: --sequence {no_labels}: ") and "labels" in err
    no_gt = tmp_path / "no_gt"
    shutil.copytree(source, no_gt)
    (no_gt / "groundtruth.txt").unlink()
    err = _one_line_error(["--out", str(out), "--sequence", str(no_gt)], capsys)
    assert err == (f"uss-demo: error: --sequence {no_gt}: {no_gt / 'groundtruth.txt'}: not "
                   "found (the demo reports ATE)")  # fmt: skip
    assert not out.exists()  # nothing was started


def test_out_that_is_a_file_is_one_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "file"
    out.write_text("x")
    err = _one_line_error(["--out", str(out)], capsys)
    assert err == f"uss-demo: error: --out={out}: is a file; expected a folder"


def test_both_trainings_start_from_the_init_with_the_same_budget(tmp_path: Path) -> None:
    """Source-only and AdaptSegNet differ in their method only; a given init replaces the
    packaged one (quoted for Hydra)."""
    plan = demo.PLANS["demo"]
    runs = {name: demo.train_overrides(plan, Path("/d"), name) for name in demo.TRAININGS}
    assert set(runs) == {"source_only", "adapted"}
    differ = set(runs["source_only"]) ^ set(runs["adapted"])
    assert differ == {"model/method=source_only", "model/method=adaptsegnet",
                      "run_name=demo_source_only", "run_name=demo_adapted"}  # fmt: skip
    assert not any("max_iters" in o for o in runs["adapted"])  # the experiment's one budget
    init = tmp_path / "my init.pt"
    assert f"model.net.weights_path='{init}'" in demo.train_overrides(
        plan, Path("/d"), "adapted", init=init
    )
    assert demo.MODELS == {"source_only": "source_only", "adabn": "source_only",
                           "adapted": "adapted"}  # fmt: skip


def test_slam_rows_repeat_on_the_demo_seed() -> None:
    for name, plan in demo.PLANS.items():
        assert plan.data.slam_seed == demo.DEMO_SLAM_SEED, name
        job = demo.slam_job(demo.VARIANTS[2], Path("/seq"), {"source_only": Path("/m.onnx")},
                            plan.slam_repeats)  # fmt: skip
        assert job.overrides()[-1] == f"slam.repeats={plan.slam_repeats}"
    assert demo.PLANS["demo"].slam_repeats == 3
    assert [v.label for v in demo.VARIANTS] == ["no filter", "ground-truth masks", "source-only",
                                                "AdaBN", "adapted", "adapted + geometry"]  # fmt: skip


def test_slam_seed_renders_only_the_slam_sequences_and_is_recorded(tmp_path: Path) -> None:
    """The SLAM sequences take ``slam_seed``; every other part keeps the data set's seeds, and
    a data set without it keeps its record (data sets rendered before are reused)."""
    spec = synthetic_data.DemoData(slam_seed=demo.DEMO_SLAM_SEED)
    plain = synthetic_data.DemoData()
    assert "slam_seed" not in plain.record()
    assert spec.record() == {**plain.record(), "slam_seed": demo.DEMO_SLAM_SEED}
    seeds = {name: kwargs["seed"] for name, _, kwargs in synthetic_data._tasks(tmp_path, spec)}
    before = {name: kwargs["seed"] for name, _, kwargs in synthetic_data._tasks(tmp_path, plain)}
    slam = {f"slam/{p}" for p in synthetic_data.SLAM_PRESETS}
    assert {seeds[n] for n in slam} == {demo.DEMO_SLAM_SEED} and {before[n] for n in slam} == {0}
    assert {n: s for n, s in seeds.items() if n not in slam} == {
        n: s for n, s in before.items() if n not in slam
    }
    assert demo.DEMO_SLAM_SEED not in set(seeds.values()) - {seeds[n] for n in slam}
    (tmp_path / synthetic_data.RECORD).write_text(yaml.safe_dump(spec.record()))
    read = synthetic_data.read_spec(tmp_path)
    assert read.slam_seed == demo.DEMO_SLAM_SEED and read.record() == spec.record()
    with pytest.raises(UssSlamError, match="slam_seed must be >= 0"):
        synthetic_data.DemoData(slam_seed=-1)

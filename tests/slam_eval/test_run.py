"""The ``uss-slam`` Hydra entry point: composed config, outputs, comparison mode, errors."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from shared_helpers import compose_slam_eval, slam_run_config

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import read_trajectory
from uss_slam.slam_eval.config import filter_defaults
from uss_slam.slam_eval.filters.build import shipped_filter_configs
from uss_slam.slam_eval.frontend.orb import OrbConfig
from uss_slam.slam_eval.products.semantic_map import MapConfig, read_ply
from uss_slam.slam_eval.run import run
from uss_slam.slam_eval.scoring.evaluation import EvalConfig
from uss_slam.slam_eval.scoring.run_folder import verify_run
from uss_slam.slam_eval.tracking.tracker import TrackerConfig

OUTPUTS = ("trajectory.txt", "metrics.json", "report.md", "trajectory.png", "ate.png", "map.ply")
STATS = {"rmse", "mean", "median", "std", "min", "max", "pairs"}


def test_defaults_come_from_the_dataclasses_and_filters() -> None:
    cfg = compose_slam_eval(["sequence.path=/x"])
    assert OmegaConf.to_container(cfg.slam.orb) == asdict(OrbConfig())
    assert OmegaConf.to_container(cfg.slam.tracker) == asdict(TrackerConfig())
    assert OmegaConf.to_container(cfg.slam.map) == asdict(MapConfig())
    assert OmegaConf.to_container(cfg.eval) == asdict(EvalConfig())
    nodes = OmegaConf.to_container(cfg.slam.filter_params)
    assert nodes == shipped_filter_configs()
    assert {
        name: {k: v for k, v in node.items() if k != "_target_"} for name, node in nodes.items()
    } == filter_defaults()
    assert filter_defaults()["geometry"]["depth_threshold"] == 0.4
    assert filter_defaults()["semantic"]["dynamic_classes"] == ["person"]
    changed = compose_slam_eval(["sequence.path=/x", "slam.orb.n_features=1500", "eval.align=sim3"])
    assert changed.slam.orb.n_features == 1500 and changed.eval.align == "sim3"


def test_defaults_compose() -> None:
    cfg = compose_slam_eval(["sequence.path=/x"])
    assert list(cfg.filters) == [] and cfg.compare is None
    assert cfg.segmenter._target_.endswith("NoSegmenter")
    assert cfg.slam.orb.n_features == 1000 and cfg.slam.orb.scale_factor == 1.2
    assert cfg.slam.orb.n_levels == 8 and cfg.slam.orb.ini_fast == 20 and cfg.slam.orb.min_fast == 7
    assert cfg.slam.filter_params.flow.threshold == 7.0
    assert cfg.slam.filter_params.geometry.max_parallax_deg == 30.0
    assert cfg.slam.filter_params.geometry.depth_threshold == 0.4
    assert cfg.slam.filter_params.object.min_points == 20


def _labels_run(synthetic_sequence, out: Path, *overrides: str) -> dict:
    """``run`` into ``out`` on 30 frames of walking_xyz, segmented by the ground-truth labels."""
    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    return run(slam_run_config(seq, out, "segmenter=labels", *overrides))


def test_run_writes_every_output(synthetic_sequence, tmp_path: Path) -> None:
    out = tmp_path / "run"
    data = _labels_run(synthetic_sequence, out, "filters=[semantic,geometry]")
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics == json.loads(json.dumps(data))
    assert set(metrics["ate"]) == STATS
    assert set(metrics["rpe"]["trans"]) == STATS and set(metrics["rpe"]["rot_deg"]) == STATS
    assert metrics["frames"] == 30 and metrics["frames_tracked"] == 30
    assert metrics["tracked_fraction"] == 1.0
    assert metrics["ate"]["pairs"] == 30 and metrics["ate"]["rmse"] < 0.05
    kp = metrics["keypoints"]
    assert set(kp["dropped"]) == {"semantic", "geometry"}
    assert kp["extracted"] - kp["kept"] == sum(kp["dropped"].values())
    assert kp["dropped"]["semantic"] > 0
    timing = metrics["timing_ms"]
    assert {"load", "segmentation", "orb", "filter.semantic", "filter.geometry", "tracking",
            "mapping", "total"} <= set(timing)  # fmt: skip
    assert metrics["fps"] > 0
    assert metrics["pipeline_to_orb_ratio"] == pytest.approx(timing["total"] / timing["orb"])
    assert set(metrics["cpu_ms"]) == set(timing) - {"load", "total"}
    assert metrics["settings"]["filters"] == ["semantic", "geometry"]
    trajectory = read_trajectory(out / "trajectory.txt")
    assert len(trajectory) == 30
    cloud = read_ply(out / "map.ply")
    assert len(cloud) == metrics["semantic_map_points"] > 1000
    person = CLASS_NAMES.index("person")
    assert person not in set(cloud.labels.tolist())  # people are filtered out of the map
    report = (out / "report.md").read_text()
    assert "| ATE [m] |" in report and "| semantic |" in report and "![trajectory.png]" in report


def test_comparison_mode(synthetic_sequence, tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    data = _labels_run(
        synthetic_sequence, out, "compare=[[semantic],[semantic,object]]", "sequence.max_frames=12"
    )
    runs = data["comparison"]
    assert list(runs) == ["baseline", "semantic", "semantic+object"]
    for name in runs:
        assert (out / name / "metrics.json").is_file()
        assert runs[name]["frames"] == 12
    table = json.loads((out / "comparison.json").read_text())
    assert table["runs"] == ["baseline", "semantic", "semantic+object"]
    rmse = table["table"]["ATE RMSE [m]"]
    expected = 100 * (rmse["baseline"] - rmse["semantic"]) / rmse["baseline"]
    assert rmse["semantic improvement %"] == pytest.approx(expected)
    text = (out / "comparison.md").read_text()
    assert "| metric | baseline | semantic | semantic+object | semantic vs baseline |" in text


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("filters=[semantic]", r"filters \['semantic'\] need a segmenter"),
        (
            "slam.orb.scale_factor=0.9",
            r"slam\.orb\.scale_factor: expected a number > 1\.0, got 0\.9",
        ),
        ("compare=[]", "compare must be a non-empty list"),
    ],
)
def test_bad_config_values_are_clear(
    synthetic_sequence, tmp_path: Path, override: str, message: str
) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    with pytest.raises(UssSlamError, match=message):
        run(slam_run_config(seq, tmp_path, override))


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "uss_slam.slam_eval.run", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_cli_runs_and_reports_errors_in_one_line(synthetic_sequence, tmp_path: Path) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path / "cli"
    done = _cli(
        [f"sequence.path={seq}", "sequence.max_frames=8", f"out_dir={out}", "progress=false"],
        tmp_path,
    )
    assert done.returncode == 0, done.stderr
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    assert (out / ".hydra" / "config.yaml").is_file()
    assert json.loads((out / "metrics.json").read_text())["frames"] == 8
    manifest = json.loads((out / "run.json").read_text())
    assert set(manifest["files"]) == {*OUTPUTS, ".hydra/config.yaml", ".hydra/hydra.yaml",
                                      ".hydra/overrides.yaml"}  # fmt: skip
    assert verify_run(out) == []

    missing = _cli([f"out_dir={tmp_path / 'x'}"], tmp_path)
    assert missing.returncode == 1
    assert missing.stderr.strip() == "uss-slam: error: Missing mandatory value: sequence.path"
    bad = _cli([f"sequence.path={tmp_path / 'nope'}", f"out_dir={tmp_path / 'y'}"], tmp_path)
    assert bad.returncode == 1
    assert bad.stderr.strip().splitlines() == [
        f"uss-slam: error: sequence.path={tmp_path / 'nope'}: does not exist; expected a TUM "
        "RGB-D sequence folder"
    ]
    camera = _cli([f"sequence.path={seq}", "sequence.camera=kinect", f"out_dir={tmp_path / 'z'}"],
                  tmp_path)  # fmt: skip
    assert camera.returncode == 1 and "sequence.camera='kinect'" in camera.stderr
    assert len(camera.stderr.strip().splitlines()) == 1


def test_cli_variant_runs_the_tables_row_and_refuses_a_disagreeing_key(
    synthetic_sequence, tmp_path: Path
) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path / "oracle"
    done = _cli([f"sequence.path={seq}", "variant=oracle", "sequence.max_frames=8",
                 f"out_dir={out}", "progress=false"], tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    settings = json.loads((out / "metrics.json").read_text())["settings"]
    assert settings["variant"] == "oracle" and settings["filters"] == ["semantic"]
    assert settings["segmenter"]["_target_"].endswith("LabelsSegmenter")
    refused = _cli([f"sequence.path={seq}", "variant=oracle", "filters=[geometry]",
                    f"out_dir={tmp_path / 'no'}"], tmp_path)  # fmt: skip
    assert refused.returncode == 1 and not (tmp_path / "no" / "run.json").exists()
    assert refused.stderr.strip().splitlines() == [
        "uss-slam: error: filters=[geometry]: variant=oracle runs filters=[semantic] "
        "(configs/variants.yaml); give one of them"
    ]

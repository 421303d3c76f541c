"""Settings that would change nothing, or less than asked, each get one warning line
``<prog>: warning: ...`` naming the key or file, and the run goes on (exit 0).

The warnings an earlier test already covers (the all-ignore labels of ``uss-eval``, the
ground truth without common time span and the all-zero depth of ``uss-slam``, the folder given
twice and the zero-weight vocabulary of ``uss-vocab``) are not repeated here.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from shared_helpers import colour_model, segmenter_props
from test_cli_matrix import run_console_script

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.cli import program
from uss_slam.core.onnx_contract import KEY_DYNAMIC_CLASSES


@pytest.fixture(scope="module")
def seq(synthetic_sequence) -> Path:
    return synthetic_sequence(preset="walking_xyz", frames=8, size=(160, 120), seed=5)


@pytest.fixture(autouse=True)
def _fresh_hydra():
    """Each in-process Hydra app composes its config anew."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    yield
    HydraConfig.instance().cfg = None
    GlobalHydra.instance().clear()


def slam(seq: Path, out: Path, *extra: str, monkeypatch, capsys) -> tuple[int, list[str]]:
    """``uss-slam`` in this process: (exit code, the warning lines on stderr)."""
    argv = [f"sequence.path={seq}", f"out_dir={out}", "progress=false", *extra]
    code, _, err = run_console_script("uss-slam", argv, monkeypatch, capsys)
    assert "Traceback" not in err and ": error: " not in err, err
    return code, [line for line in err.splitlines() if ": warning: " in line]


def compared_runs(out: Path) -> list[str]:
    return list(json.loads((out / "run.json").read_text())["runs"])


# ------------------------------------------------------------------------------ compare


def test_a_compare_set_given_twice_runs_once_with_a_warning(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    out = tmp_path / "out"
    code, warnings = slam(seq, out, "segmenter=labels", "compare=[[semantic],[flow],[semantic]]",
                          monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0
    assert warnings == [
        "uss-slam: warning: compare[2] [semantic] repeats compare[0], which runs once; "
        "compare[2] is left out"
    ]
    assert compared_runs(out) == ["baseline", "semantic", "flow"]


def test_an_empty_compare_set_is_the_baseline_and_is_left_out_with_a_warning(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    out = tmp_path / "out"
    code, warnings = slam(seq, out, "segmenter=labels", "compare=[[],[semantic]]",
                          monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0
    assert warnings == [
        "uss-slam: warning: compare[0] is empty: the baseline, which runs anyway; "
        "compare[0] is left out"
    ]
    assert compared_runs(out) == ["baseline", "semantic"]
    folders = sorted(p.name for p in out.iterdir() if p.is_dir() and p.name[0] != ".")
    assert folders == ["baseline", "semantic"]


def test_filters_beside_compare_are_named_as_unused(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    out = tmp_path / "out"
    code, warnings = slam(seq, out, "segmenter=labels", "filters=[geometry]",
                          "compare=[[semantic]]", monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0
    assert len(warnings) == 1
    assert warnings[0].startswith("uss-slam: warning: filters=[geometry] is not used: with "
                                  "compare, each set of compare names its filters")  # fmt: skip
    assert compared_runs(out) == ["baseline", "semantic"]
    metrics = json.loads((out / "baseline" / "metrics.json").read_text())
    assert metrics["keypoints"]["flagged"] == {}  # the baseline ran without geometry


def test_a_distinct_compare_without_filters_warns_nothing(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    code, warnings = slam(seq, tmp_path / "out", "segmenter=labels",
                          "compare=[[semantic],[semantic,geometry]]",
                          monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0 and warnings == []


# ------------------------------------------------------------------------------ ground truth


def test_a_sequence_without_groundtruth_warns_that_ate_and_rpe_are_na(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    """``groundtruth.txt`` is optional: the run writes its trajectory and map (exit 0), with one
    line saying that nothing is scored."""
    copy = tmp_path / "s"
    shutil.copytree(seq, copy)
    (copy / "groundtruth.txt").unlink()
    out = tmp_path / "out"
    code, warnings = slam(copy, out, monkeypatch=monkeypatch, capsys=capsys)
    assert code == 0
    assert warnings == [
        f"uss-slam: warning: {copy}: no groundtruth.txt, so ATE and RPE are n/a (the "
        "trajectory and the map are written)"
    ]
    assert (out / "trajectory.txt").is_file()
    assert json.loads((out / "metrics.json").read_text())["ate"] is None


# ------------------------------------------------------------------------------ dynamic classes


def test_the_semantic_filter_without_dynamic_classes_warns_once(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    """Used in two runs of a comparison, and built once per run: still one line."""
    out = tmp_path / "out"
    code, warnings = slam(seq, out, "segmenter=labels", "compare=[[semantic],[semantic,flow]]",
                          "slam.filter_params.semantic.dynamic_classes=[]",
                          monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0
    assert warnings == [
        "uss-slam: warning: slam.filter_params.semantic.dynamic_classes is empty: the semantic "
        "filter drops no keypoint"
    ]
    metrics = json.loads((out / "semantic" / "metrics.json").read_text())
    assert metrics["keypoints"]["flagged"] == {"semantic": 0}


def test_empty_dynamic_classes_of_an_unused_semantic_filter_warn_nothing(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    code, warnings = slam(seq, tmp_path / "out", "slam.filter_params.semantic.dynamic_classes=[]",
                          monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0 and warnings == []


@pytest.mark.parametrize("threshold", [None, 0.3])
def test_an_onnx_model_without_dynamic_classes_warns_when_threshold_is_set(
    seq: Path, tmp_path: Path, monkeypatch, capsys, threshold: float | None
) -> None:
    """The model's ``uss_slam.dynamic_classes`` is what ``segmenter.threshold`` acts on: empty,
    the threshold changes no label (one warning naming the model and the key). Without a
    threshold the metadata is not read (the semantic filter has its own classes): no line."""
    model = colour_model(tmp_path / "m.onnx", segmenter_props(CLASS_NAMES, dynamic=()))
    extra = [] if threshold is None else [f"segmenter.threshold={threshold}"]
    code, warnings = slam(seq, tmp_path / "out", "segmenter=onnx", f"segmenter.path={model}",
                          *extra, monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0
    if threshold is None:
        assert warnings == []
    else:
        assert warnings == [
            f"uss-slam: warning: {model}: metadata {KEY_DYNAMIC_CLASSES} is empty (the model "
            "names no dynamic class), so segmenter.threshold=0.3 changes no label"
        ]


# ------------------------------------------------------------------------------ clamped counts


def test_more_calibration_frames_than_the_folder_holds_warns_with_both_numbers(
    synthetic_sequence, capsys
) -> None:
    """``calibration.frames=1000`` on 20 frames: the 20 are used (10 + 10), with one line."""
    from uss_slam.export.quantize import read_calibration_frames

    root = synthetic_sequence(preset="walking_xyz", frames=20, size=(160, 120), seed=5)
    with program("uss-export"):
        calibration, evaluation = read_calibration_frames(root, 1000)
        assert capsys.readouterr().err.splitlines() == [
            "uss-export: warning: calibration.frames=1000 asks for 1000 calibration and 1000 "
            f"evaluation frames, but {root / 'rgb.txt'} lists 20: 10 calibrate and 10 evaluate"
        ]
        assert len(calibration) == 10 and len(evaluation) == 10
        read_calibration_frames(root, 10)  # exactly as many: no line
        assert capsys.readouterr().err == ""


def test_more_eval_overlays_than_frames_warns(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    model = colour_model(tmp_path / "m.onnx", segmenter_props(CLASS_NAMES))
    out = tmp_path / "eval"
    argv = [str(model), "--sequence", str(seq), "--overlays", "50", "--out", str(out)]
    code, _, err = run_console_script("uss-eval", argv, monkeypatch, capsys)
    assert code == 0, err
    assert err.strip().splitlines() == [
        "uss-eval: warning: --overlays 50: the data has 8 frames; 8 overlays are written, "
        "one per frame"
    ]
    assert len(json.loads((out / "eval.json").read_text())["overlays"]) == 8


# ------------------------------------------------------------ declared in the schemas


def test_a_setting_whose_switch_is_off_warns_naming_both_keys(
    seq: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    """A setting declared ``needs=<switch>`` in its schema, set while the switch is off."""
    code, warnings = slam(seq, tmp_path / "out", "slam.map.octomap_resolution=0.1",
                          "slam.local_ba=false", "slam.local_ba_params.covisibility=5",
                          monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert code == 0
    assert warnings == [
        "uss-slam: warning: slam.map.octomap_resolution is set but changes nothing while "
        "slam.map.octomap is false",
        "uss-slam: warning: slam.local_ba_params.covisibility is set but changes nothing while "
        "slam.local_ba is false",
    ]


def test_an_export_calibration_without_int8_warns_naming_its_keys(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    """``uss-export calibration.frames=4 calibration.root=DIR`` without ``int8=true``: the
    export goes on; one warning names both keys and the switch."""
    from omegaconf import OmegaConf

    from uss_slam.core.cli import program
    from uss_slam.export.cli import ExportOptions, ExportSchema

    cfg = OmegaConf.merge(
        OmegaConf.structured(ExportSchema),
        {"ckpt_path": str(tmp_path / "m.ckpt"), "out_dir": str(tmp_path),
         "calibration": {"root": str(tmp_path), "frames": 4}},
    )  # fmt: skip
    (tmp_path / "m.ckpt").write_bytes(b"not read here")
    with program("uss-export"):
        ExportOptions.from_config(cfg)
    assert capsys.readouterr().err.strip().splitlines() == [
        "uss-export: warning: calibration.root, calibration.frames are set but change nothing "
        "while int8 is false"
    ]


def _experiments_warnings(capsys, overrides: list[str]) -> list[str]:
    """The warning lines of ``uss-experiments``' check of the config ``overrides`` compose."""
    from uss_slam.core.cli import program
    from uss_slam.pipelines.experiments.experiment import check
    from uss_slam.pipelines.runs import compose_config

    cfg = compose_config("experiments", overrides)
    with program("uss-experiments"):
        check(cfg)
    return [ln for ln in capsys.readouterr().err.splitlines() if ": warning: " in ln]


def test_experiments_adabn_methods_without_adabn_warn(capsys) -> None:
    """``grid.adabn_methods`` is declared ``needs="adabn"``: set while ``grid.adabn=false``,
    one warning naming both keys (the plan is made as without it)."""
    warnings = _experiments_warnings(
        capsys, ["grid.adabn=false", "grid.adabn_methods=[source_only,adaptsegnet]"]
    )
    assert warnings == [
        "uss-experiments: warning: grid.adabn_methods is set but changes nothing while "
        "grid.adabn is false"
    ]


def test_experiments_orbslam3_settings_without_orbslam3_warn(capsys) -> None:
    warnings = _experiments_warnings(capsys, ["slam.orbslam3.repeats=5"])
    assert warnings == [
        "uss-experiments: warning: slam.orbslam3.repeats is set but changes nothing while "
        "systems does not list orbslam3"
    ]


def test_synth_timing_with_the_source_style_warns(tmp_path: Path, monkeypatch, capsys) -> None:
    """``uss-synth sequence --style source --timing rolling``: the timing is the target style's
    sensor only; accepted with one warning naming ``--timing``."""
    argv = ["sequence", "--preset", "walking_static", "--style", "source", "--timing", "rolling",
            "--frames", "2", "--size", "32x24", "--out", str(tmp_path / "s"), "--quiet"]  # fmt: skip
    code, _, err = run_console_script("uss-synth", argv, monkeypatch, capsys)
    warnings = [line for line in err.splitlines() if ": warning: " in line]
    assert code == 0 and warnings == [
        "uss-synth: warning: --timing applies to the target style's sensor only; ignored with "
        "--style source"
    ], err

"""``uss-train experiment=uss_slam_paper`` on VOC / SBD / COCO / TUM fixture roots; the demo and
CI experiments with ``data=real`` on VOC-format photos, scored by ``uss-eval`` (``data/val=voc``).

The paper's ResNet-101 takes minutes per step on a CPU and its ImageNet weights would be
downloaded, so these runs swap in the small CI segmenter (``model/net=deeplab_small``) without
weights: everything else (data config, selection, manifest, loss weights, discriminators) is the
paper experiment's.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict
from realdata_helpers import (
    coco_json,
    paint_voc,
    rect,
    standard_scenes,
    write_coco,
    write_sbd,
    write_tum,
    write_voc,
)

from uss_slam.core.tum_io import read_file_list
from uss_slam.datasets.coco import COCOSegmentation
from uss_slam.datasets.sbd import SBDSegmentation
from uss_slam.datasets.selection import MANIFEST_NAME, SelectedSources
from uss_slam.datasets.tum import TUMFrames
from uss_slam.datasets.voc import VOCSegmentation

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
SHAPE = (40, 48)
pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")

# The paper's selection keeps images showing person AND chair AND monitor: in each fixture set
# that is scene 2008_000001 only (VOC id 2008_000001, SBD id 2009_000001, COCO image 1).
EXPECTED_IDS = {"voc": ["2008_000001"], "sbd": ["2009_000001"], "coco": ["1"]}


@pytest.fixture(scope="module")
def roots(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("real")
    scenes = standard_scenes(SHAPE)
    labels = {name: paint_voc(SHAPE, scene) for name, scene in scenes.items()}
    names = list(labels)
    voc = write_voc(base / "voc", labels, {"trainval": names, "val": names[3:]})
    sbd_labels = {name.replace("2008", "2009"): label for name, label in labels.items()}
    write_sbd(base / "sbd", {**labels, **sbd_labels}, {"train": [*names, *sbd_labels]})
    coco = write_coco(
        base / "coco", {k + 1: (f"{n}.jpg", s) for k, (n, s) in enumerate(scenes.items())}, SHAPE
    )
    tum = write_tum(base / "tum" / "rgbd_dataset_freiburg3_walking_xyz", 6)
    return {"voc": voc.parent.parent, "sbd": base / "sbd", "coco": coco, "tum": tum}


def _overrides(roots: dict[str, Path], log_dir: Path) -> list[str]:
    return [
        "experiment=uss_slam_paper",
        f"data.source.voc.root={roots['voc']}",
        f"data.source.sbd.root={roots['sbd']}",
        f"data.source.coco.root={roots['coco']}",
        f"data.target.roots=[{roots['tum']}]",
        "model/net=deeplab_small",  # ResNet-101 is minutes per CPU step (see the docstring)
        "model.net.backbone_weights=null",  # never download in tests
        "model.net.allow_random_init=true",  # no weights file in tests
        "trainer=cpu",
        "logger=none",
        "data.num_workers=0",
        "data.source.transform.crop_size=33",
        "data.target.transform.crop_size=33",
        f"paths.log_dir={log_dir}",
    ]


def _compose(overrides: list[str], output_dir: Path) -> DictConfig:
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(output_dir)
        cfg.hydra.job.num = 0
    HydraConfig().set_config(cfg)
    return cfg


def test_paper_experiment_composes_the_three_source_sets(
    roots: dict[str, Path], tmp_path: Path
) -> None:
    cfg = _compose(_overrides(roots, tmp_path / "logs"), tmp_path / "run")
    source = cfg.data.source
    assert source.voc.split == "trainval" and source.sbd.split == "train"
    assert source.selection.classes == ["person", "chair", "monitor"]
    assert source.selection.require == "all" and source.selection.exclude_voc_val
    assert OmegaConf.to_container(source.coco.categories)["monitor"][:2] == ["tv", "tv/monitor"]
    assert cfg.model.net.backbone == "resnet_small" and cfg.model.method.discriminator.n_layers == 5
    data = instantiate(cfg.data)
    sources = data.source
    assert isinstance(sources, SelectedSources)
    assert [type(s) for s in sources.sets.values()] == [
        VOCSegmentation,
        SBDSegmentation,
        COCOSegmentation,
    ]
    chosen = {
        name: [sources.sets[name].items[i].name for i in ids]
        for name, ids in sources.chosen.items()
    }
    assert chosen == EXPECTED_IDS
    assert sources.summary["sbd"].overlap == 5  # the 2008_* ids: in VOC trainval (2 in val)
    assert isinstance(data.target, TUMFrames) and len(data.target) == 6 and data.val is None
    assert (tmp_path / "logs" / "cache" / "coco").is_dir()  # the COCO masks are cached
    batch = sources[0]
    assert batch["image"].shape == (3, 33, 33) and batch["name"] == "voc/2008_000001"


def test_paper_experiment_runs_fast_dev_run(roots: dict[str, Path], tmp_path: Path) -> None:
    from uss_slam.train.train import train

    cfg = _compose(
        [*_overrides(roots, tmp_path / "logs"), "+trainer.fast_dev_run=true"], tmp_path / "run"
    )
    metrics = train(cfg)
    assert metrics["iteration"] == 1.0
    assert all(np.isfinite(v) for v in metrics.values())
    manifest = json.loads((tmp_path / "run" / MANIFEST_NAME).read_text())
    assert {name: s["ids"] for name, s in manifest["sets"].items()} == EXPECTED_IDS


@pytest.mark.slow
def test_uss_train_command_on_fixture_roots(roots: dict[str, Path], tmp_path: Path) -> None:
    """The console script itself (a fresh process: imports, Hydra app, exit code)."""
    exe = Path(sys.executable).parent / "uss-train"
    result = subprocess.run(
        [str(exe), *_overrides(roots, tmp_path / "logs"), "+trainer.fast_dev_run=true"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    (manifest,) = (tmp_path / "logs" / "train" / "runs" / "uss_slam_paper").glob(
        f"*/{MANIFEST_NAME}"
    )
    assert {
        n: s["ids"] for n, s in json.loads(manifest.read_text())["sets"].items()
    } == EXPECTED_IDS


def test_a_missing_root_is_one_line_naming_it(roots: dict[str, Path], tmp_path: Path) -> None:
    cfg = _compose(
        [*_overrides(roots, tmp_path / "logs"), f"data.source.sbd.root={tmp_path / 'nowhere'}"],
        tmp_path / "run",
    )
    with pytest.raises(Exception, match=r"nowhere: SBD root not found") as info:
        instantiate(cfg.data)
    from uss_slam.core.cli import user_error

    assert user_error(info.value) is not None  # uss-train turns it into one line, exit 1


def test_on_error_reaches_every_set_and_the_target(roots: dict[str, Path], tmp_path: Path) -> None:
    cfg = _compose(
        [*_overrides(roots, tmp_path / "logs"), "data.source.on_error=skip"], tmp_path / "run"
    )
    data = cfg.data
    assert {data.source[name].on_error for name in ("voc", "sbd", "coco")} == {"skip"}
    assert data.target.on_error == "skip"


def test_validation_on_held_out_labelled_target_frames(
    roots: dict[str, Path], tmp_path: Path
) -> None:
    sequence = write_tum(tmp_path / "walking_static", 40)
    (sequence / "labels").mkdir()
    for image in (sequence / "rgb").iterdir():
        cv2.imwrite(str(sequence / "labels" / image.name), np.ones((24, 32), np.uint8))
    overrides = [*_overrides(roots, tmp_path / "logs"), f"data.target.roots=[{sequence}]"]
    data = instantiate(_compose([*overrides, "data/val=tum_holdout"], tmp_path / "run").data)
    # holdout 0.1 of 40 frames = the last 4, validated at stride 5; training stops 30 frames
    # before them.
    stamp = read_file_list(sequence / "rgb.txt").stamps[36]
    assert [item.name for item in data.val.items] == [f"walking_static/{stamp:.6f}"]
    assert len(data.target) == 40 - 4 - 30 and data.val.labelled
    assert data.val[0]["label"].shape == (24, 32)


def test_validation_on_a_coco_export_of_target_frames(
    roots: dict[str, Path], tmp_path: Path
) -> None:
    sequence = roots["tum"]
    frames = sorted(p.name for p in (sequence / "rgb").iterdir())
    shape = (24, 32)
    scenes = {
        k: (f"rgb/{name}", [rect(shape, 2, 2, 12, 20, 15)]) for k, name in enumerate(frames[:2])
    }
    export = tmp_path / "walking_xyz_labels.json"
    export.write_text(json.dumps(coco_json(scenes, shape)))
    overrides = [
        *_overrides(roots, tmp_path / "logs"),
        "data/val=coco",
        f"data.val.annotations={export}",
        f"data.val.images={sequence}",
    ]
    data = instantiate(_compose(overrides, tmp_path / "run").data)
    assert isinstance(data.val, COCOSegmentation) and len(data.val) == 2
    assert (data.val.read_label(0) == 1).sum() == 10 * 18
    assert len(data.target) == 6 - 2  # the labelled frames never train the adaptation


def test_data_real_composes_any_subset_of_source_sets(
    roots: dict[str, Path], tmp_path: Path
) -> None:
    overrides = [
        "data=real",
        "data/source=[coco,sbd]",
        f"data.source.coco.root={roots['coco']}",
        f"data.source.sbd.root={roots['sbd']}",
        "data.source.selection.exclude_voc_val=false",  # no VOC set: nothing to overlap with
        f"data.target.roots=[{roots['tum']}]",
        f"paths.log_dir={tmp_path / 'logs'}",
    ]
    data = instantiate(_compose(overrides, tmp_path / "run").data)
    assert list(data.source.sets) == ["coco", "sbd"]  # the order of data/source
    assert data.source.selection.require == "any"
    # any of person / chair / monitor: 4 of 5 COCO images, 8 of 10 SBD ids
    assert [len(ids) for ids in data.source.chosen.values()] == [4, 8]


# ------------------------------------------------- the shipped experiments on real-format photos


@pytest.fixture(scope="module")
def photo_roots(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A VOC tree of 12 photos in two sizes (a person, and a chair or a monitor, in each) with
    train / val / test splits, and a TUM sequence of 8 frames."""
    base = tmp_path_factory.mktemp("photos")
    labels = {}
    for k in range(12):
        shape = (40, 48) if k % 2 == 0 else (44, 36)
        h, w = shape
        person = rect(shape, 4 + k % 5, 6, 4 + k % 5 + w // 3, h - 4, 15)
        other = rect(shape, w // 2, h // 2, w - 2, h - 2, 9 if k % 3 else 20)
        labels[f"2010_{k:06d}"] = paint_voc(shape, [person, other])
    names = list(labels)
    splits = {"train": names[:7], "val": names[7:9], "test": names[9:]}
    voc = write_voc(base / "voc", labels, splits)
    tum = write_tum(base / "tum" / "rgbd_dataset_freiburg3_walking_xyz", 8, (48, 64))
    return {"voc": voc, "tum": tum, "labels": labels, "test": splits["test"]}


def _run(command: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / command
    result = subprocess.run([str(exe), *args], cwd=cwd, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    return result


@pytest.mark.slow
def test_demo_and_ci_train_on_real_photos_and_uss_eval_scores_the_test_split(
    photo_roots: dict[str, Any], tmp_path: Path
) -> None:
    """``uss-train experiment=demo data=real`` and ``experiment=ci data=real`` on VOC-format
    photos and TUM frames (validated on ``data/val=voc``), then ``uss-eval`` with
    ``data/val=voc`` on the test split."""
    voc, tum = photo_roots["voc"], photo_roots["tum"]
    logs = tmp_path / "logs"
    common = [
        "data=real",
        f"data.source.voc.root={voc}",
        f"data.target.roots=[{tum}]",
        "data/val=voc",
        f"data.val.root={voc}",
        "data.num_workers=0",
        "logger=none",
        f"paths.log_dir={logs}",
    ]
    # the demo: 2 iterations, one validation (after the precise BatchNorm pass on whole photos)
    _run("uss-train", ["experiment=demo", *common, "model.max_iters=2",
                       "data.iterations_per_epoch=2"], tmp_path)  # fmt: skip
    _run("uss-train", ["experiment=ci", *common], tmp_path)  # 4 iterations, 2 validations
    for run_name, iterations in (("demo", 2), ("ci", 4)):
        (run,) = (logs / "train" / "runs" / run_name).iterdir()
        manifest = json.loads((run / MANIFEST_NAME).read_text())
        assert manifest["sets"]["voc"]["ids"] == list(photo_roots["labels"])[:7]
        last = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
        assert last["state_dict"] and last["iteration"] == iterations
        assert len(list((run / "checkpoints").glob("best_*.ckpt"))) == 1  # val/mIoU was logged

    (demo_run,) = (logs / "train" / "runs" / "demo").iterdir()
    out = tmp_path / "eval"
    result = _run(
        "uss-eval",
        [str(demo_run / "checkpoints" / "last.ckpt"), "data=real", "data/val=voc",
         f"data.val.root={voc}", "data.val.split=test", "--out", str(out)],
        tmp_path,
    )  # fmt: skip
    assert f"wrote {out / 'eval.json'}" in result.stdout
    scored = json.loads((out / "eval.json").read_text())
    assert scored["frames"] == len(photo_roots["test"]) == 3
    # every labelled pixel of the test photos is counted once, under its project class
    lut = np.zeros(256, np.int64)
    lut[[15, 9, 20]] = [1, 2, 3]
    truth = np.zeros(4, np.int64)
    for name in photo_roots["test"]:
        truth += np.bincount(lut[photo_roots["labels"][name]].ravel(), minlength=4)
    assert np.array(scored["confusion_matrix"]).sum(axis=1).tolist() == truth.tolist()
    assert truth[1] > 0  # the person class is in the test split

"""The Hydra configs and the `uss-train` glue: every experiment composes and instantiates,
`ci` runs (fast_dev_run and a real short run), checkpoints resume exactly, errors are one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra.errors import InstantiationException
from hydra.utils import instantiate
from lightning.pytorch import Trainer
from lightning.pytorch.callbacks import ModelCheckpoint
from shared_helpers import compose_train, data_overrides
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from train_helpers import ADVERSARIAL_SCALARS

from uss_slam.datasets.datamodule import UDADataModule
from uss_slam.models import DeepLabV2, PatchDiscriminator
from uss_slam.train.module import AdversarialSegmentation, NonFiniteLossError
from uss_slam.train.train import _instantiate_all, resolve_ckpt_path, train

EXPERIMENTS = sorted(
    p.stem for p in (Path(__file__).parents[2] / "configs/experiment").glob("*.yaml")
)


def test_experiment_list_is_complete() -> None:
    assert {"ci", "demo", "uss_slam_paper"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_composes_and_instantiates(
    experiment: str, uda_data: dict[str, Path], tmp_path: Path
) -> None:
    overrides = [f"experiment={experiment}", *data_overrides(uda_data)]
    if experiment == "uss_slam_paper":
        # Real-data paths are `???` in the file: fill them; never download weights in tests.
        overrides = [
            f"experiment={experiment}",
            "data/source=[voc]",  # the synthetic VOC tree stands in for VOC + SBD + COCO
            f"data.source.voc.root={uda_data['voc']}",
            "data.source.voc.split=train",
            "data.source.selection.require=any",
            f"data.target.roots=[{uda_data['target']}]",
            "model.net.backbone_weights=null",
            "model.net.allow_random_init=true",  # no weights file in tests
            "trainer.accelerator=cpu",
        ]
    if experiment == "pretrain":  # one VOC tree is every split of the pretraining set
        overrides = [f"experiment={experiment}", f"data.source.root={uda_data['voc']}"]
    cfg = compose_train(overrides, tmp_path)
    datamodule = instantiate(cfg.data)
    model = instantiate(cfg.model)
    callbacks = _instantiate_all(cfg.callbacks)
    loggers = _instantiate_all(cfg.logger)
    trainer = instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)
    assert isinstance(datamodule, UDADataModule) and isinstance(trainer, Trainer)
    assert isinstance(model, AdversarialSegmentation) and isinstance(model.segmenter, DeepLabV2)
    assert len(datamodule.source) > 0 and len(datamodule.target) > 0
    if experiment == "pretrain":  # source-only on labelled photos: no discriminators
        assert model.method.name == "source_only" and model.method.discriminators is None
        assert datamodule.val is not None and len(datamodule.val) > 0
        return
    assert (
        isinstance(model.method.d_aux, PatchDiscriminator)
        and model.method.d_aux is not model.method.d_main
    )
    assert len(datamodule.source) > 0 and len(datamodule.target) > 0
    (opt_seg, opt_d), _ = model.configure_optimizers()
    assert isinstance(opt_seg, torch.optim.SGD) and isinstance(opt_d, torch.optim.Adam)
    assert opt_seg.defaults["nesterov"] and opt_seg.defaults["momentum"] == 0.9
    assert opt_seg.defaults["weight_decay"] == 1e-4
    assert opt_d.defaults["betas"] == (0.9, 0.99)
    if experiment == "uss_slam_paper":
        assert model.segmenter.backbone_name == "resnet101"
        assert model.segmenter.batchnorm == "reference"
        assert opt_seg.param_groups[0]["lr"] == 2.5e-4 and opt_seg.param_groups[1]["lr"] == 2.5e-3
        assert opt_d.defaults["lr"] == 1e-4
        assert (
            model.loss_weights.lambda_seg_aux == 0.1 and model.loss_weights.lambda_seg_main == 1.0
        )
        assert model.method.lambda_adv_aux == 0.002
        assert model.method.lambda_adv_main == 0.01
        assert model.method.d_main.n_layers == 5 and model.poly_power == 0.9
        assert cfg.data.source.transform.crop_size == 321


@pytest.mark.parametrize("experiment", ["ci", "demo"])
@pytest.mark.parametrize("n_layers", [4, 5, 6, 7])
def test_documented_depth_sweep_fits_the_experiment_crops(
    experiment: str, n_layers: int, tmp_path: Path
) -> None:
    # `uss-train -m experiment=ci|demo model.method.discriminator.n_layers=4,5,6,7` must run every job:
    # the crop must survive n stride-2 convolutions (a 65-pixel crop breaks n = 7).
    cfg = compose_train(
        [f"experiment={experiment}", f"model.method.discriminator.n_layers={n_layers}"], tmp_path
    )
    crops = {cfg.data.source.transform.crop_size, cfg.data.target.transform.crop_size}
    assert len(crops) == 1
    crop = crops.pop()
    d = instantiate(cfg.model.method.discriminator)()
    with torch.no_grad():
        out = d(torch.rand(1, cfg.model.net.num_classes, crop, crop))
    assert out.shape == (1, 1, crop // 2**n_layers, crop // 2**n_layers)


def test_paper_experiment_leaves_real_data_paths_to_fill(tmp_path: Path) -> None:
    cfg = compose_train(["experiment=uss_slam_paper"], tmp_path)
    from omegaconf import OmegaConf

    for name in ("voc", "sbd", "coco"):
        assert OmegaConf.is_missing(cfg.data.source[name], "root")
    assert OmegaConf.is_missing(cfg.data.target, "roots")
    assert cfg.model.net.weights_path is None and cfg.model.net.batchnorm == "reference"
    # No weights file given: refused in one line before any training work.
    with pytest.raises(InstantiationException) as error:
        instantiate(cfg.model.net)
    assert str(error.value.__cause__).startswith("model.net.weights_path: not set")


def test_ci_fast_dev_run(uda_data: dict[str, Path], tmp_path: Path) -> None:
    cfg = compose_train(
        ["experiment=ci", "+trainer.fast_dev_run=true", *data_overrides(uda_data)], tmp_path
    )
    metrics = train(cfg)
    assert "train/loss_seg_src_main" in metrics and "val/mIoU" in metrics


def _events(path: Path) -> EventAccumulator:
    events = EventAccumulator(str(path), size_guidance={"images": 0, "scalars": 0})
    events.Reload()
    return events


def test_ci_run_logs_validates_and_checkpoints(uda_data: dict[str, Path], tmp_path: Path) -> None:
    cfg = compose_train(["experiment=ci", *data_overrides(uda_data)], tmp_path)
    metrics = train(cfg)
    assert metrics["iteration"] == 4
    assert 0.0 <= metrics["val/mIoU"] <= 1.0
    # The discriminators' watch: 4 iterations make one (short) block per head.
    assert metrics["train/d_at_chance"] in (0.0, 1.0)
    for head in ("aux", "main"):
        assert 0.0 <= metrics[f"train/d_acc_{head}_peak"] <= 1.0
        assert metrics[f"train/d_acc_{head}_last"] == metrics[f"train/d_acc_{head}_peak"]
    events = _events(tmp_path / "tensorboard")
    scalars = set(events.Tags()["scalars"])
    expected = ADVERSARIAL_SCALARS | {
        "val/mIoU",
        "val/IoU/background",
        "val/IoU/person",
        "val/IoU/chair",
        "val/IoU/monitor",
    }
    assert expected <= scalars
    # One logged point per iteration (x axis = iterations, not optimiser steps).
    assert [e.step for e in events.Scalars("train/loss_seg_src_main")] == [0, 1, 2, 3]
    assert [e.step for e in events.Scalars("val/mIoU")] == [1, 3]
    images = set(events.Tags()["images"])
    assert {"train/source", "train/target", "val/target"} <= images
    panel = events.Images("train/source")[0]
    crop = cfg.data.source.transform.crop_size
    assert (panel.width, panel.height) == (3 * crop, crop)  # input | prediction | label
    # Checkpoints: best by val/mIoU and last; plain tensors (weights_only) with the iteration.
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert "last.ckpt" in names and any(n.startswith("best_iter") for n in names)
    last = torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=True)
    assert last["iteration"] == 4
    assert len(last["optimizer_states"]) == 2 and len(last["lr_schedulers"]) == 2
    assert last["lr_schedulers"][0]["last_epoch"] == 4
    prefixes = {k.split(".")[0] for k in last["state_dict"]}
    assert {"segmenter", "method"} <= prefixes
    assert any(k.startswith("method.d_main.") for k in last["state_dict"])


def _final_state(path: Path) -> dict:
    return torch.load(path, weights_only=True)


def test_resume_equals_uninterrupted(uda_data: dict[str, Path], tmp_path: Path) -> None:
    common = [
        "experiment=ci",
        *data_overrides(uda_data),
        "logger=none",
        "+trainer.limit_val_batches=1",
    ]
    train(compose_train(common, tmp_path / "full"))
    full = _final_state(tmp_path / "full" / "checkpoints" / "last.ckpt")

    train(compose_train([*common, "trainer.max_epochs=1"], tmp_path / "first"))
    first = _final_state(tmp_path / "first" / "checkpoints" / "last.ckpt")
    assert first["iteration"] == 2
    ckpt = tmp_path / "first" / "checkpoints" / "last.ckpt"
    train(compose_train([*common, f"ckpt_path={ckpt}"], tmp_path / "second"))
    resumed = _final_state(tmp_path / "second" / "checkpoints" / "last.ckpt")

    assert resumed["iteration"] == full["iteration"] == 4
    assert not all(
        torch.equal(first["state_dict"][k], full["state_dict"][k]) for k in full["state_dict"]
    )
    for key, value in full["state_dict"].items():
        torch.testing.assert_close(resumed["state_dict"][key], value, rtol=0, atol=1e-6)
    for mine, ref in zip(resumed["optimizer_states"], full["optimizer_states"], strict=True):
        for pid, state in ref["state"].items():
            for name, tensor in state.items():
                if torch.is_tensor(tensor):
                    torch.testing.assert_close(mine["state"][pid][name], tensor, rtol=0, atol=1e-6)
    assert resumed["lr_schedulers"] == full["lr_schedulers"]


def test_non_finite_loss_stops_and_keeps_the_last_good_checkpoint(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    cfg = compose_train(
        [
            "experiment=ci",
            *data_overrides(uda_data),
            "logger=none",
            "+trainer.limit_val_batches=1",
            # Diverges at the first iteration of the second epoch (after last.ckpt at 2).
            "+callbacks.poison._target_=train_helpers.PoisonAt",
            "+callbacks.poison.iteration=2",
        ],
        tmp_path,
    )
    with pytest.raises(NonFiniteLossError, match="non-finite loss_seg_src_main .* iteration 2"):
        train(cfg)
    checkpoints = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert "last.ckpt" in checkpoints and all(
        "iter0000002" in n for n in checkpoints if "best" in n
    )
    last = torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=True)
    assert last["iteration"] == 2
    assert all(
        torch.isfinite(v).all() for v in last["state_dict"].values() if v.is_floating_point()
    )


def test_ckpt_path_last_finds_the_newest_earlier_run(tmp_path: Path) -> None:
    runs = tmp_path / "logs" / "train" / "runs" / "ci"
    for stamp in ("2026-01-01_00-00-00", "2026-01-02_00-00-00"):
        (runs / stamp / "checkpoints").mkdir(parents=True)
        (runs / stamp / "checkpoints" / "last.ckpt").write_bytes(b"x")
        os.utime(
            runs / stamp / "checkpoints" / "last.ckpt", (1e9, 1e9 + len(stamp) + int(stamp[9]))
        )
    current = runs / "2026-01-03_00-00-00"
    cfg = compose_train(["experiment=ci", "ckpt_path=last"], current)
    cfg.paths.log_dir = str(tmp_path / "logs")
    assert resolve_ckpt_path(cfg) == str(runs / "2026-01-02_00-00-00" / "checkpoints" / "last.ckpt")
    cfg.run_name = "demo"
    with pytest.raises(Exception, match="no checkpoints/last.ckpt in this run's folder .* nor in"):
        resolve_ckpt_path(cfg)


def test_ckpt_path_last_resumes_in_place_in_a_run_folder_given_again(tmp_path: Path) -> None:
    """``hydra.run.dir=X ckpt_path=last`` after a run into ``X`` was stopped: ``X``'s own
    ``last.ckpt`` (there was no earlier run under ``paths.log_dir`` to find)."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.ckpt").write_bytes(b"x")
    cfg = compose_train(["experiment=ci", "ckpt_path=last"], run)
    cfg.paths.log_dir = str(tmp_path / "logs")
    assert resolve_ckpt_path(cfg) == str(run / "checkpoints" / "last.ckpt")


def test_checkpoint_callbacks_keep_best_and_last(tmp_path: Path) -> None:
    cfg = compose_train([], tmp_path)
    best, last = [c for c in _instantiate_all(cfg.callbacks) if isinstance(c, ModelCheckpoint)]
    assert best.monitor == "val/mIoU" and best.mode == "max" and best.save_top_k == 1
    assert last.monitor is None and last.filename == "last"


def _uss_train(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "uss-train"
    return subprocess.run([str(exe), *args], cwd=cwd, capture_output=True, text=True, timeout=600)


def test_cli_bad_data_path_is_one_line_and_exit_1(tmp_path: Path) -> None:
    result = _uss_train("experiment=ci", f"paths.data_dir={tmp_path / 'nowhere'}", cwd=tmp_path)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("uss-train: error: data.source.root=")
    assert "does not exist; expected a folder" in lines[0]
    assert str(tmp_path / "nowhere") in lines[0]

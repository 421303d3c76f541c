"""Every shipped experiment composes with ``data=real``; the labelled photo validation sets
(``data/val=voc``, ``data/val=sbd``); the data loading that ``trainer=gpu`` / ``ddp`` set.

The runs themselves (``uss-train experiment=demo data=real``, ``experiment=ci``, ``uss-eval``
with ``data/val=voc``) are in ``tests/datasets/test_real_train.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf, open_dict

sys.path.insert(0, str(Path(__file__).resolve().parent / "datasets"))
from realdata_helpers import paint_voc, rect, write_sbd, write_tum, write_voc  # noqa: E402

from uss_slam.core.errors import UssSlamError  # noqa: E402
from uss_slam.datasets.datamodule import with_transform  # noqa: E402
from uss_slam.datasets.sbd import SBDSegmentation  # noqa: E402
from uss_slam.datasets.selection import SelectedSources  # noqa: E402
from uss_slam.datasets.tum import TUMFrames  # noqa: E402
from uss_slam.datasets.voc import VOCSegmentation  # noqa: E402
from uss_slam.train.precise_bn import PreciseBatchNorm  # noqa: E402

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
EXPERIMENTS = sorted(p.stem for p in (CONFIG_DIR / "experiment").glob("*.yaml"))
# Photos of two sizes, as real photo sets have (a batch of them cannot be stacked).
SHAPES = ((40, 48), (44, 36))


def _compose(overrides: list[str], tmp_path: Path) -> DictConfig:
    """``train.yaml`` with ``overrides``, outputs under ``tmp_path``, set as the HydraConfig."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(tmp_path / "run")
        cfg.hydra.job.num = 0
        cfg.paths.log_dir = str(tmp_path / "logs")
    HydraConfig().set_config(cfg)
    return cfg


def _fill_missing(node: object, path: Path) -> None:
    """Mandatory values (``???``) under ``node`` set to paths under ``path``."""
    if isinstance(node, DictConfig):
        for key in list(node):
            if OmegaConf.is_missing(node, key):
                node[key] = str(path / str(key))
            else:
                _fill_missing(node._get_node(key), path / str(key))


@pytest.fixture(scope="module")
def photos(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """VOC and SBD trees of 6 photos (a person, a chair or a monitor each) and a TUM sequence."""
    base = tmp_path_factory.mktemp("photos")
    labels = {}
    for k in range(6):
        shape = SHAPES[k % 2]
        h, w = shape
        scene = [rect(shape, 2, 4, w // 3, h - 2, 15), rect(shape, w // 2, h // 2, w - 1, h - 1, 9)]
        labels[f"2010_{k:06d}"] = paint_voc(shape, scene)
    names = list(labels)
    splits = {"train": names[:4], "val": names[4:]}
    return {
        "voc": write_voc(base / "voc", labels, splits),
        "sbd": write_sbd(base / "sbd", labels, splits),
        "tum": write_tum(base / "tum" / "rgbd_dataset_freiburg3_walking_xyz", 5),
    }


def _real(photos: dict[str, Path]) -> list[str]:
    return [
        "data=real",
        f"data.source.voc.root={photos['voc']}",
        f"data.target.roots=[{photos['tum']}]",
    ]


@pytest.mark.parametrize("val", [None, "voc", "sbd", "tum_holdout"])
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_composes_and_resolves_with_real_data(
    experiment: str, val: str | None, photos: dict[str, Path], tmp_path: Path
) -> None:
    overrides = [f"experiment={experiment}", *_real(photos)]
    if val in ("voc", "sbd"):
        overrides += [f"data/val={val}", f"data.val.root={photos[val]}"]
    elif val is not None:
        overrides.append(f"data/val={val}")
    cfg = _compose(overrides, tmp_path)
    assert cfg.hydra.runtime.choices.data == "real"
    with open_dict(cfg):
        del cfg["hydra"]  # Hydra's own node has mandatory values no app fills
    # the roots of source sets that only the paper reads (SBD, COCO), an experiment's own
    # paths (pretrain.root): placeholders, as a user gives them
    _fill_missing(cfg, tmp_path / "mandatory")
    container = OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
    assert isinstance(container, dict)
    data = container["data"]
    # no synthetic-only keys leak into the real data config: data.val is a whole dataset or none
    assert data.get("val") is None if val is None else "_target_" in data["val"]
    assert data["source"]["_target_"] == "uss_slam.datasets.selection.SelectedSources"
    bn = container["callbacks"].get("precise_bn")
    if bn is not None:  # the demo: the data config's own sets, read whole
        assert {k: v for k, v in bn["source"]["dataset"].items() if k != "transform"} == {
            k: v for k, v in data["source"].items() if k != "transform"
        }
        assert bn["target"]["dataset"]["roots"] == [str(photos["tum"])]
        assert bn["batch_size"] == data["val_batch_size"] == 1  # photos differ in size


def test_demo_precise_batchnorm_reads_whole_real_photos(
    photos: dict[str, Path], tmp_path: Path
) -> None:
    cfg = _compose(["experiment=demo", *_real(photos)], tmp_path)
    callback = instantiate(cfg.callbacks.precise_bn)
    assert isinstance(callback, PreciseBatchNorm) and callback.batch_size == 1
    source, target = callback.datasets["source"], callback.datasets["target"]
    assert isinstance(source, SelectedSources) and isinstance(target, TUMFrames)
    assert len(source) == 4 and len(target) == 5  # VOC train (all show a person), every frame
    # whole photos (not the 129-px training crops), in their own sizes
    shapes = [tuple(source[k]["image"].shape[1:]) for k in range(len(source))]
    assert shapes == [SHAPES[k % 2] for k in range(4)]
    assert tuple(target[0]["image"].shape) == (3, 24, 32)
    # the training sets keep their crops: the callback's are copies
    datamodule = instantiate(cfg.data)
    assert tuple(datamodule.source[0]["image"].shape) == (3, 129, 129)
    # the statistics pass runs on them (batches of one photo of either size)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4))
    module = type("Module", (), {"segmenter": net, "adaptation": True})()
    trainer = type("Trainer", (), {"sanity_checking": False})()
    callback.on_validation_start(trainer, module)  # type: ignore[arg-type]
    assert int(net[1].num_batches_tracked) == 4


@pytest.mark.parametrize(("name", "kind"), [("voc", VOCSegmentation), ("sbd", SBDSegmentation)])
def test_labelled_photo_validation_sets(
    name: str, kind: type, photos: dict[str, Path], tmp_path: Path
) -> None:
    cfg = _compose([*_real(photos), f"data/val={name}", f"data.val.root={photos[name]}"], tmp_path)
    val = instantiate(cfg.data).val
    assert isinstance(val, kind) and val.labelled and val.split == "val"
    assert [item.name for item in val.items] == ["2010_000004", "2010_000005"]
    sample = val[1]  # whole photo, project classes: person 1, chair 2
    assert tuple(sample["image"].shape) == (3, *SHAPES[1])
    assert set(sample["label"].unique().tolist()) == {0, 1, 2}


def test_labelled_photo_validation_root_is_required(
    photos: dict[str, Path], tmp_path: Path
) -> None:
    cfg = _compose([*_real(photos), "data/val=voc"], tmp_path)
    assert OmegaConf.is_missing(cfg.data.val, "root")
    missing = tmp_path / "nowhere"
    cfg = _compose([*_real(photos), "data/val=sbd", f"data.val.root={missing}"], tmp_path)
    with pytest.raises(Exception, match=rf"{missing}: SBD root not found"):
        instantiate(cfg.data)


@pytest.mark.parametrize(
    ("overrides", "pin_memory", "workers"),
    [
        ([], False, 2),  # data=synthetic on the default trainer
        (["trainer=cpu"], False, 2),
        (["trainer=gpu"], True, 4),
        (["trainer=ddp"], True, 4),
        (["data=real", "trainer=gpu"], True, 4),
        (["experiment=uss_slam_paper"], True, 4),  # the paper's trainer=gpu
        (["experiment=uss_slam_paper", "trainer=ddp"], True, 4),
        (["experiment=demo", "trainer=gpu"], True, 1),  # an experiment's own count wins
        (["experiment=ci", "trainer=ddp"], True, 0),
        (["trainer=gpu", "data.pin_memory=false", "data.num_workers=8"], False, 8),
    ],
)
def test_gpu_trainers_pin_memory_and_set_workers(
    overrides: list[str], pin_memory: bool, workers: int, tmp_path: Path
) -> None:
    cfg = _compose(overrides, tmp_path)
    assert cfg.data.pin_memory is pin_memory and cfg.data.num_workers == workers
    if pin_memory and "trainer=ddp" not in overrides:  # the GPU trainer itself is unchanged
        assert cfg.trainer.accelerator == "gpu" and cfg.trainer.devices == 1
    if "trainer=ddp" in overrides:
        assert cfg.trainer.devices == 2 and cfg.trainer.strategy.find_unused_parameters


def test_with_transform_copies_and_checks(photos: dict[str, Path]) -> None:
    frames = TUMFrames([photos["tum"]])
    flipped = with_transform(frames, lambda sample: {**sample, "image": sample["image"].flip(-1)})
    assert flipped is not frames and flipped.items is frames.items
    assert torch.equal(flipped[0]["image"], frames.load(0)["image"].flip(-1))  # raw, flipped
    with pytest.raises(UssSlamError, match="with_transform: list has no transform to replace"):
        with_transform([1, 2], lambda sample: sample)  # type: ignore[arg-type]

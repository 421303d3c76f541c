"""UDADataModule on the synthetic data: batch structure, seeded streams, worker independence."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from uss_slam.datasets.datamodule import UDADataModule
from uss_slam.datasets.transforms import eval_transform, train_transform
from uss_slam.datasets.tum import TUMFrames
from uss_slam.datasets.voc import VOCSegmentation

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def datasets(
    synthetic_voc: Callable[..., Path], synthetic_sequence: Callable[..., Path]
) -> dict[str, object]:
    crop = train_transform(crop_size=41, scale_range=(0.5, 1.0), hflip=True)
    return {
        "source": VOCSegmentation(synthetic_voc(), transform=crop),
        "target": TUMFrames(synthetic_sequence(), transform=crop),
        "val": TUMFrames(
            synthetic_sequence(frames=6, size=(160, 120), seed=1),
            labels=True,
            transform=eval_transform(),
        ),
    }


def _batches(dm: UDADataModule, epoch: int = 0) -> list[dict]:
    loader = dm.train_dataloader()
    for dataloader in loader.flattened:
        dataloader.sampler.set_epoch(epoch)
    return [batch for batch, *_ in loader]


def test_train_batches_hold_source_and_target(datasets: dict) -> None:
    dm = UDADataModule(**datasets, batch_size=2, iterations_per_epoch=3, val_batch_size=3)
    batches = _batches(dm)
    assert len(batches) == 3
    source, target = batches[0]["source"], batches[0]["target"]
    assert source["image"].shape == (2, 3, 41, 41) and source["image"].dtype == torch.float32
    assert source["label"].shape == (2, 41, 41) and source["label"].dtype == torch.int64
    assert set(source["label"].unique().tolist()) <= {0, 1, 2, 3, 255}
    assert set(target) == {"image", "name"} and target["image"].shape == (2, 3, 41, 41)
    val = next(iter(dm.val_dataloader()))
    assert val["image"].shape == (3, 3, 120, 160) and val["label"].shape == (3, 120, 160)


def test_streams_are_seeded_and_independent_of_workers(datasets: dict) -> None:
    base = dict(**datasets, batch_size=2, iterations_per_epoch=2)
    inline = _batches(UDADataModule(**base, num_workers=0, seed=5), epoch=1)
    workers = _batches(UDADataModule(**base, num_workers=2, seed=5), epoch=1)
    other_seed = _batches(UDADataModule(**base, num_workers=0, seed=6), epoch=1)
    for a, b in zip(inline, workers, strict=True):
        for domain in ("source", "target"):
            assert a[domain]["name"] == b[domain]["name"]
            assert torch.equal(a[domain]["image"], b[domain]["image"])
    assert not torch.equal(inline[0]["source"]["image"], other_seed[0]["source"]["image"])
    # The next epoch continues the stream instead of repeating it.
    epoch2 = _batches(UDADataModule(**base, num_workers=0, seed=5), epoch=2)
    assert not torch.equal(inline[0]["source"]["image"], epoch2[0]["source"]["image"])


def test_no_validation_set_gives_no_val_loader(datasets: dict) -> None:
    dm = UDADataModule(datasets["source"], datasets["target"], val=None)
    assert dm.val_dataloader() == []


def _load_in_a_worker(context: bool) -> str:
    """In a joblib worker: a data loader with one worker process, as the training's loaders."""
    from torch.utils.data import DataLoader

    from uss_slam.datasets.datamodule import worker_context

    extra = {"multiprocessing_context": worker_context(1)} if context else {}
    try:
        return str([b.tolist() for b in DataLoader(list(range(4)), batch_size=2, num_workers=1,
                                                   **extra)])  # fmt: skip
    except AttributeError as error:
        return f"failed: {error}"


@pytest.mark.filterwarnings("ignore:Got pickle error")
def test_loaders_start_workers_inside_joblib_workers() -> None:
    """A training inside joblib's worker processes (``uss-experiments launcher=joblib``) finds
    joblib's ``loky`` start method as the process's default, whose processes a data loader
    cannot start (``'Process' object has no attribute 'env'``); the loaders' context is the
    platform's default method there, and Python's default (None) elsewhere."""
    joblib = pytest.importorskip("joblib")
    from uss_slam.datasets.datamodule import worker_context

    assert worker_context(0) is None and worker_context(2) is None  # here: Python's default
    plain, ours = joblib.Parallel(n_jobs=2)(
        joblib.delayed(_load_in_a_worker)(c) for c in (False, True)
    )
    assert plain.startswith("failed: ")  # what the training jobs ran into
    assert ours == "[[0, 1], [2, 3]]"

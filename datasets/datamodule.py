"""``UDADataModule``: labelled source + unlabelled target for training, labelled target frames
for validation.

Training batches are ``{"source": {"image", "label", "name"}, "target": {"image", "name"}}``
(Lightning ``CombinedLoader``): ``image (N, 3, H, W)`` float32 normalised, ``label (N, H, W)``
int64. An epoch is ``iterations_per_epoch`` batches of endless, seeded per-domain sample streams
(:mod:`uss_slam.datasets.sampling`), so the data of every iteration is fixed by the seed alone:
resuming from an epoch-end checkpoint replays exactly what an uninterrupted run would see.

A source that records its selection (:class:`~uss_slam.datasets.selection.SelectedSources`)
writes ``source_manifest.json`` into the run directory (the trainer's ``default_root_dir``) at
``setup``, on the global-zero process only.
"""

from __future__ import annotations

import copy
import multiprocessing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any

from lightning.pytorch import LightningDataModule
from lightning.pytorch.utilities import CombinedLoader
from torch.utils.data import DataLoader, Dataset

from uss_slam.core.errors import UssSlamError
from uss_slam.core.ranges import MAX_THREADS, Range
from uss_slam.datasets.sampling import SeededDataset, StreamSampler

SOURCE_DOMAIN = 0
TARGET_DOMAIN = 1


def _loaders(iterables: Any) -> list[Any]:
    """The loaders of ``trainer.train_dataloader`` (a loader, or a dict / list of them)."""
    if isinstance(iterables, CombinedLoader):
        return list(iterables.flattened)
    if isinstance(iterables, Mapping):
        return [x for value in iterables.values() for x in _loaders(value)]
    if isinstance(iterables, (list, tuple)):
        return [x for value in iterables for x in _loaders(value)]
    return [] if iterables is None else [iterables]


class UDADataModule(LightningDataModule):
    """Source / target training streams and a validation set.

    Args:
        source: labelled source dataset (e.g. :class:`~uss_slam.datasets.voc.VOCSegmentation`,
            or the selected concatenation of VOC / SBD / COCO,
            :class:`~uss_slam.datasets.selection.SelectedSources`).
        target: target dataset (e.g. unlabelled :class:`~uss_slam.datasets.tum.TUMFrames`).
        val: labelled target frames for validation (``None``: no validation).
        batch_size: samples per domain per iteration and rank (the paper: 1).
        iterations_per_epoch: training batches per Lightning epoch (validation and checkpoints
            happen at epoch ends by default).
        val_batch_size: validation batch size.
        num_workers: data-loading worker processes per loader.
        seed: seed of the sample streams and their augmentation.
        pin_memory: pin host memory (GPU training).
        manifest_dir: where the source manifest goes (default: the trainer's run directory).
    """

    def __init__(
        self,
        source: Dataset,
        target: Dataset,
        val: Dataset | None = None,
        batch_size: Annotated[int, Range(min=1)] = 1,
        iterations_per_epoch: Annotated[int, Range(min=1)] = 1000,
        val_batch_size: Annotated[int, Range(min=1)] = 1,
        num_workers: Annotated[int, Range(min=0, max=MAX_THREADS)] = 0,
        seed: int = 0,
        pin_memory: bool = False,
        manifest_dir: str | Path | None = None,
    ) -> None:
        super().__init__()  # the values' ranges: the config's schema (uss-train)
        self.source = source
        self.target = target
        self.val = val
        self.batch_size = batch_size
        self.iterations_per_epoch = iterations_per_epoch
        self.val_batch_size = val_batch_size
        self.num_workers = num_workers
        self.seed = seed
        self.pin_memory = pin_memory
        self.manifest_dir = manifest_dir
        self.manifest_path: Path | None = None
        self._streams_checked = False

    def setup(self, stage: str) -> None:
        write = getattr(self.source, "write_manifest", None)
        if write is None or self.manifest_path is not None:
            return
        trainer = self.trainer
        if trainer is not None and not trainer.is_global_zero:
            return
        directory = self.manifest_dir
        if directory is None and trainer is not None:
            directory = trainer.default_root_dir
        if directory is not None:
            self.manifest_path = write(directory)

    def _rank_and_world(self) -> tuple[int, int]:
        """This process's shard of the sample streams: Lightning's distributed-sampler arguments
        under a multi-process strategy, else the whole stream."""
        kwargs = self.trainer.distributed_sampler_kwargs if self.trainer is not None else None
        if not kwargs:
            return 0, 1
        return int(kwargs.get("rank", 0)), int(kwargs.get("num_replicas", 1))

    def on_before_batch_transfer(self, batch: Any, dataloader_idx: int) -> Any:
        # Checked once, at the first training batch: with trainer.use_distributed_sampler=true
        # Lightning re-creates the training loaders around a DistributedSampler, which would
        # shard (and shuffle) the already sharded, seeded streams a second time.
        trainer = self.trainer
        if not self._streams_checked and trainer is not None and trainer.training:
            for loader in _loaders(trainer.train_dataloader):
                sampler = getattr(loader, "sampler", None)
                if not isinstance(sampler, StreamSampler):
                    raise UssSlamError(
                        "UDADataModule shards its sample streams itself: set "
                        "trainer.use_distributed_sampler=false (Lightning replaced the training "
                        f"sampler with {type(sampler).__name__})"
                    )
            self._streams_checked = True
        return batch

    def _stream(self, dataset: Dataset, domain: int) -> DataLoader:
        rank, world = self._rank_and_world()
        sampler = StreamSampler(
            len(dataset),  # type: ignore[arg-type]
            batch_size=self.batch_size,
            batches_per_epoch=self.iterations_per_epoch,
            seed=self.seed,
            domain=domain,
            rank=rank,
            world_size=world,
        )
        return DataLoader(
            SeededDataset(dataset),
            batch_size=self.batch_size,
            sampler=sampler,
            drop_last=True,
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
            pin_memory=self.pin_memory,
            multiprocessing_context=worker_context(self.num_workers),
        )

    def train_dataloader(self) -> CombinedLoader:
        self._streams_checked = False
        loaders = {
            "source": self._stream(self.source, SOURCE_DOMAIN),
            "target": self._stream(self.target, TARGET_DOMAIN),
        }
        return CombinedLoader(loaders, mode="min_size")

    def val_dataloader(self) -> DataLoader | list[Any]:
        if self.val is None:
            return []
        return DataLoader(
            self.val,
            batch_size=self.val_batch_size,
            shuffle=False,
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
            pin_memory=self.pin_memory,
            multiprocessing_context=worker_context(self.num_workers),
        )


def with_transform(dataset: Dataset, transform: Callable[[Any], Any]) -> Dataset:
    """A shallow copy of ``dataset`` that applies ``transform`` to its samples instead of its
    own (the files, selection and items stay those of ``dataset``).

    What lets a config read the data config's own training sets another way, whatever their
    layout: e.g. whole images with the evaluation transform for BatchNorm statistics
    (``dataset: ${data.source}``, ``${data.target}``) instead of random training crops.
    """
    if not hasattr(dataset, "transform"):
        raise UssSlamError(
            f"with_transform: {type(dataset).__name__} has no transform to replace (expected "
            "a dataset of uss_slam.datasets: VOC, SBD, COCO, TUM frames or selected sources)"
        )
    copied = copy.copy(dataset)
    copied.transform = transform  # type: ignore[attr-defined]
    return copied


def worker_context(num_workers: int) -> Any:
    """The multiprocessing context of the loaders' worker processes: None (Python's default)
    unless the process's default start method is not one of Python's own. A training run
    inside joblib's worker processes (``uss-experiments launcher=joblib``) finds joblib's
    ``loky`` method there, whose processes a data loader cannot start; it gets the platform's
    default method instead."""
    if num_workers == 0:
        return None
    method = multiprocessing.get_start_method(allow_none=True)
    if method is None or method in multiprocessing.get_all_start_methods():
        return None
    return multiprocessing.get_context(multiprocessing.get_all_start_methods()[0])

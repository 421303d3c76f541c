"""Resumable, rank-aware sample streams for iteration-based training.

Training draws an endless stream of samples from each domain: pass ``k`` over a dataset of
``n`` samples is a random permutation seeded by ``(seed, domain, k)``, and each position of the
stream carries its own augmentation seed. Position ``p`` is fixed by ``(epoch, batch, rank,
slot)``, so the data an iteration sees does not depend on how often training was interrupted,
on ``num_workers``, or on which worker loads it; under DDP the ranks read interleaved,
disjoint positions.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, NamedTuple

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler


class SampleKey(NamedTuple):
    """What a :class:`StreamSampler` yields: dataset index and the sample's augmentation seed."""

    index: int
    seed: int


class StreamSampler(Sampler[SampleKey]):
    """One epoch = ``batches_per_epoch`` batches of ``batch_size`` keys of this rank's stream.

    Lightning calls :meth:`set_epoch` at the start of every epoch (also after resuming), which
    selects the stream positions ``[(epoch·L + b)·W + rank]·B + j``.
    """

    def __init__(
        self,
        dataset_size: int,
        batch_size: int,
        batches_per_epoch: int,
        seed: int = 0,
        domain: int = 0,
        rank: int = 0,
        world_size: int = 1,
        shuffle: bool = True,
    ) -> None:
        if dataset_size <= 0:
            raise ValueError("cannot sample from an empty dataset")
        if batch_size <= 0 or batches_per_epoch <= 0:
            raise ValueError("batch_size and batches_per_epoch must be positive")
        if not 0 <= rank < world_size:
            raise ValueError(f"rank {rank} outside world of size {world_size}")
        self.dataset_size = dataset_size
        self.batch_size = batch_size
        self.batches_per_epoch = batches_per_epoch
        self.seed = seed
        self.domain = domain
        self.rank = rank
        self.world_size = world_size
        self.shuffle = shuffle
        self.epoch = 0
        self._perm_pass = -1
        self._perm = np.arange(dataset_size)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.batches_per_epoch * self.batch_size

    def position(self, batch: int, slot: int) -> int:
        """Stream position of ``slot`` in batch ``batch`` of the current epoch on this rank."""
        global_batch = self.epoch * self.batches_per_epoch + batch
        return (global_batch * self.world_size + self.rank) * self.batch_size + slot

    def key(self, position: int) -> SampleKey:
        sweep, offset = divmod(position, self.dataset_size)
        if self.shuffle and sweep != self._perm_pass:
            rng = np.random.default_rng([self.seed, self.domain, sweep])
            self._perm = rng.permutation(self.dataset_size)
            self._perm_pass = sweep
        seed = np.random.SeedSequence([self.seed, self.domain, position]).generate_state(1)[0]
        return SampleKey(int(self._perm[offset]), int(seed))

    def __iter__(self) -> Iterator[SampleKey]:
        for batch in range(self.batches_per_epoch):
            for slot in range(self.batch_size):
                yield self.key(self.position(batch, slot))


class SeededDataset(Dataset):
    """Wraps a dataset so that ``dataset[SampleKey(i, s)]`` is ``dataset[i]`` with torch's RNG
    seeded by ``s`` (the transforms draw from it); the caller's RNG state is left untouched."""

    def __init__(self, dataset: Dataset) -> None:
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)  # type: ignore[arg-type]

    def __getitem__(self, key: SampleKey) -> Any:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(key.seed)
            return self.dataset[key.index]

"""Seeded, resumable, rank-sharded sample streams."""

from __future__ import annotations

import torch
from torch.utils.data import Dataset

from uss_slam.datasets.sampling import SampleKey, SeededDataset, StreamSampler


def _epochs(sampler: StreamSampler, epochs: range) -> list[list[SampleKey]]:
    out = []
    for epoch in epochs:
        sampler.set_epoch(epoch)
        out.append(list(sampler))
    return out


def test_every_pass_is_a_permutation_and_passes_differ() -> None:
    sampler = StreamSampler(dataset_size=7, batch_size=1, batches_per_epoch=7, seed=3)
    first, second = (sorted(k.index for k in keys) for keys in _epochs(sampler, range(2)))
    assert first == second == list(range(7))
    a, b = _epochs(sampler, range(2))
    assert [k.index for k in a] != [k.index for k in b]
    assert len({k.seed for k in a + b}) == 14  # every position its own augmentation seed


def test_a_fresh_sampler_at_epoch_e_replays_the_uninterrupted_stream() -> None:
    uninterrupted = _epochs(StreamSampler(5, 2, 3, seed=1), range(4))
    resumed = StreamSampler(5, 2, 3, seed=1)
    resumed.set_epoch(2)
    assert list(resumed) == uninterrupted[2]


def test_ranks_read_disjoint_interleaved_positions() -> None:
    ranks = [StreamSampler(100, 2, 5, seed=0, rank=r, world_size=2) for r in (0, 1)]
    positions = [{s.position(b, j) for b in range(5) for j in range(2)} for s in ranks]
    assert not positions[0] & positions[1]
    assert positions[0] | positions[1] == set(range(20))
    keys = [list(s) for s in ranks]
    assert {k.seed for k in keys[0]}.isdisjoint({k.seed for k in keys[1]})


def test_domains_draw_different_streams() -> None:
    source = list(StreamSampler(50, 1, 10, seed=0, domain=0))
    target = list(StreamSampler(50, 1, 10, seed=0, domain=1))
    assert [k.index for k in source] != [k.index for k in target]


class _Noise(Dataset):
    def __len__(self) -> int:
        return 3

    def __getitem__(self, index: int) -> torch.Tensor:
        return torch.rand(4) + index


def test_seeded_dataset_is_reproducible_and_leaves_global_rng_alone() -> None:
    dataset = SeededDataset(_Noise())
    torch.manual_seed(0)
    expected_next = torch.rand(1)
    torch.manual_seed(0)
    a = dataset[SampleKey(1, 42)]
    b = dataset[SampleKey(1, 42)]
    assert torch.equal(a, b)
    assert not torch.equal(a, dataset[SampleKey(1, 43)])
    assert torch.equal(torch.rand(1), expected_next)

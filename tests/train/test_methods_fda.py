"""FDA (``model/method=fda``): the amplitude swap and the entropy penalty against plain
re-statements of FDA's code (numpy FFTs, its ``EntropyLoss``), its bad inputs, and one
training iteration that changes the segmenter only."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from shared_helpers import compose_train
from train_helpers import fit_repeated

from uss_slam.core.errors import UssSlamError
from uss_slam.testing import reference_step as bench
from uss_slam.train.methods.fda import FDA, charbonnier_entropy, low_frequency_swap
from uss_slam.train.train import check_method_data


def fda_source_to_target(src: np.ndarray, trg: np.ndarray, beta: float) -> np.ndarray:
    """FDA's ``FDA_source_to_target_np`` written out: full 2-D FFT per channel, the four
    low-frequency corner squares of side ``floor(min(h, w) * beta)`` of the amplitude taken from
    the target, the source phase kept, the real part of the inverse."""
    fft_src, fft_trg = np.fft.fft2(src, axes=(-2, -1)), np.fft.fft2(trg, axes=(-2, -1))
    amp_src, pha_src = np.abs(fft_src), np.angle(fft_src)
    amp_trg = np.abs(fft_trg)
    h, w = src.shape[-2:]
    b = int(np.floor(min(h, w) * beta))
    amp_src[..., :b, :b] = amp_trg[..., :b, :b]
    amp_src[..., :b, w - b :] = amp_trg[..., :b, w - b :]
    amp_src[..., h - b :, :b] = amp_trg[..., h - b :, :b]
    amp_src[..., h - b :, w - b :] = amp_trg[..., h - b :, w - b :]
    return np.real(np.fft.ifft2(amp_src * np.exp(1j * pha_src), axes=(-2, -1)))


@pytest.mark.parametrize(("shape", "beta"), [((33, 41), 0.01), ((33, 41), 0.09), ((20, 20), 0.2)])
def test_swap_is_fdas(shape: tuple[int, int], beta: float) -> None:
    gen = torch.Generator().manual_seed(0)
    src = torch.rand(3, 3, *shape, generator=gen, dtype=torch.float64)
    trg = torch.rand(2, 3, *shape, generator=gen, dtype=torch.float64)
    mine = low_frequency_swap(src, trg, beta)
    for i in range(3):  # source crop i takes target crop i mod 2
        expected = fda_source_to_target(src[i].numpy(), trg[i % 2].numpy(), beta)
        np.testing.assert_allclose(mine[i].numpy(), expected, rtol=0, atol=1e-5)
    if int(min(shape) * beta) == 0:
        torch.testing.assert_close(mine, src.float())


def test_swap_carries_the_targets_mean_colour() -> None:
    """The DC term is in the swapped square: every channel's mean becomes the target's."""
    src = torch.rand(1, 3, 24, 32) * 0.2
    trg = torch.rand(1, 3, 24, 32) * 0.2 + 0.7
    out = low_frequency_swap(src, trg, 0.05)
    torch.testing.assert_close(out.mean(dim=(-2, -1)), trg.mean(dim=(-2, -1)), atol=1e-5, rtol=0)


def test_charbonnier_entropy_is_fdas() -> None:
    logits = torch.randn(2, 4, 5, 7)
    size = (9, 13)
    up = F.interpolate(logits, size=size, mode="bilinear", align_corners=True)
    p, logp = F.softmax(up, dim=1), F.log_softmax(up, dim=1)
    ent = -(p * logp).sum(dim=1) / math.log(4)  # FDA's `ent / 2.9444` for its 19 classes
    expected = ((ent**2.0 + 1e-8) ** 2.0).mean()
    torch.testing.assert_close(charbonnier_entropy(logits, size, 2.0), expected)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"beta": 0.0}, r"model.method.beta must be in \(0, 0.5\], got 0.0"),
        ({"beta": 0.6}, r"model.method.beta must be in \(0, 0.5\], got 0.6"),
        ({"beta": True}, r"model.method.beta must be in \(0, 0.5\], got True"),
        ({"eta": 0}, r"model.method.eta must be a number > 0, got 0"),
        ({"lambda_ent_main": -1}, r"model.method.lambda_ent_main: expected a number >= 0"),
        ({"entropy_start": 2}, r"model.method.entropy_start must be in \[0, 1\], got 2.0"),
    ],
)
def test_bad_settings_name_the_key(kwargs: dict, message: str) -> None:
    with pytest.raises(UssSlamError, match=message):
        FDA(**kwargs)


def test_unequal_crops_and_no_target_are_refused_before_any_work(tmp_path: Path) -> None:
    cfg = compose_train(
        ["experiment=ci", "model/method=fda", "data.target.transform.crop_size=97"], tmp_path
    )
    with pytest.raises(UssSlamError, match=r"data.source.transform.crop_size \(129\) and"):
        check_method_data(cfg)
    cfg = compose_train(["experiment=ci", "model/method=fda", "data.target=null"], tmp_path)
    with pytest.raises(UssSlamError, match="model/method=fda trains on target frames"):
        check_method_data(cfg)
    check_method_data(compose_train(["experiment=ci", "model/method=fda"], tmp_path))


def test_an_iteration_trains_on_the_styled_source_and_the_entropy_from_its_start() -> None:
    """Before ``entropy_start`` the step equals source-only's on the swapped crops; after it,
    the entropy term moves the segmenter too (same start weights, same batch)."""
    from uss_slam.train.image_space import from_rgb, to_rgb
    from uss_slam.train.methods import SourceOnly

    batch = bench.random_batch(33, 2)
    torch.manual_seed(0)
    fda = bench.build_module("resnet_small", max_iters=4)
    start = {k: v.clone() for k, v in fda.segmenter.state_dict().items()}
    fda.method = FDA(beta=0.1, entropy_start=0.5)
    fit_repeated(fda, batch, 1)
    styled = from_rgb(low_frequency_swap(to_rgb(batch["source"]["image"]),
                                         to_rgb(batch["target"]["image"]), 0.1))  # fmt: skip
    plain = bench.build_module("resnet_small", max_iters=4)
    plain.segmenter.load_state_dict(start)
    plain.method = SourceOnly()
    fit_repeated(plain, {**batch, "source": {**batch["source"], "image": styled}}, 1)
    for key, value in fda.segmenter.state_dict().items():
        torch.testing.assert_close(value, plain.segmenter.state_dict()[key], rtol=0, atol=1e-6)

    late = bench.build_module("resnet_small", max_iters=4)
    late.segmenter.load_state_dict(start)
    late.method = FDA(beta=0.1, entropy_start=0.0, lambda_ent_main=10.0)
    fit_repeated(late, batch, 1)
    moved = [not torch.allclose(v, fda.segmenter.state_dict()[k]) for k, v in
             late.segmenter.state_dict().items() if v.is_floating_point()]  # fmt: skip
    assert any(moved)

"""``PreciseBatchNorm`` (the demo experiment's BatchNorm statistics): exact statistics of the
chosen domain's images, modes and momenta restored, weights untouched, domain by adaptation."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from hydra.utils import instantiate
from shared_helpers import compose_train, data_overrides
from torch import nn

from uss_slam.core.errors import UssSlamError
from uss_slam.train.precise_bn import (
    PreciseBatchNorm,
    adabn,
    evenly_spaced,
    recompute_batchnorm,
)


class Images(torch.utils.data.Dataset):
    def __init__(self, images: list[torch.Tensor]) -> None:
        self.images = images

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        return {"image": self.images[index]}


def _net() -> nn.Sequential:
    torch.manual_seed(0)
    return nn.Sequential(nn.Conv2d(3, 5, 3), nn.BatchNorm2d(5), nn.ReLU(), nn.BatchNorm2d(5))


def _images(n: int, offset: float, size: int = 9) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(int(offset * 10) + n)
    return [torch.randn(3, size, size, generator=g) * 2 + offset for _ in range(n)]


def test_evenly_spaced_indices() -> None:
    assert evenly_spaced(4, 10) == [0, 2, 5, 7]
    assert evenly_spaced(3, 3) == [0, 1, 2]
    assert evenly_spaced(8, 3) == [0, 1, 2]
    assert evenly_spaced(2, 0) == []


def test_statistics_are_the_exact_ones_of_the_images() -> None:
    net = _net().eval()
    net[1].momentum = 0.3
    weights = {k: v.detach().clone() for k, v in net.named_parameters()}
    images = _images(6, offset=1.5)
    assert recompute_batchnorm(net, Images(images), list(range(6)), batch_size=6) == 6
    with torch.no_grad():
        features = net[0](torch.stack(images))  # what the first BatchNorm sees
    mean = features.mean(dim=(0, 2, 3))
    var = features.var(dim=(0, 2, 3), unbiased=True)
    torch.testing.assert_close(net[1].running_mean, mean, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(net[1].running_var, var, rtol=1e-4, atol=1e-5)
    # modes, momenta and weights as before
    assert not any(m.training for m in net.modules())
    assert net[1].momentum == 0.3 and net[3].momentum == 0.1
    for key, value in weights.items():
        assert torch.equal(dict(net.named_parameters())[key], value), key


def test_batches_are_averaged_and_earlier_statistics_forgotten() -> None:
    net = _net().train()
    with torch.no_grad():  # running statistics of some other data first
        for _ in range(3):
            net(torch.stack(_images(4, offset=-3.0)))
    images = _images(8, offset=2.0)
    recompute_batchnorm(net, Images(images), list(range(8)), batch_size=4)
    with torch.no_grad():
        f1, f2 = (net[0](torch.stack(images[k : k + 4])) for k in (0, 4))
    expected = 0.5 * (f1.mean(dim=(0, 2, 3)) + f2.mean(dim=(0, 2, 3)))
    torch.testing.assert_close(net[1].running_mean, expected, rtol=1e-5, atol=1e-5)
    assert all(m.training for m in net.modules())  # train mode restored


def test_mixed_sizes_in_a_batch_are_an_error_and_leave_momenta() -> None:
    net = _net()
    images = _images(2, offset=0.0, size=9) + _images(2, offset=0.0, size=11)
    with pytest.raises(UssSlamError, match="differ in size"):
        recompute_batchnorm(net, Images(images), [0, 1, 2, 3], batch_size=4)
    assert net[1].momentum == 0.1
    assert recompute_batchnorm(net, Images(images), [0, 1, 2, 3], batch_size=1) == 4


@pytest.mark.parametrize(
    ("setting", "adaptation", "domain"),
    [
        (None, True, "source"),  # the default: the same statistics for every method
        (None, False, "source"),
        ("target", False, "target"),
        ("auto", True, "target"),  # auto: the domain an adapted model is deployed on
        ("auto", False, "source"),
    ],
)
def test_callback_uses_the_configured_domain(
    setting: str | None, adaptation: bool, domain: str
) -> None:
    source, target = _images(4, offset=-2.0), _images(4, offset=3.0)
    kwargs = {} if setting is None else {"domain": setting}
    callback = PreciseBatchNorm(Images(source), Images(target), images=4, batch_size=4, **kwargs)
    module = SimpleNamespace(adaptation=adaptation, segmenter=_net())
    callback.on_validation_start(SimpleNamespace(sanity_checking=False), module)  # type: ignore[arg-type]
    chosen = source if domain == "source" else target
    with torch.no_grad():
        mean = module.segmenter[0](torch.stack(chosen)).mean(dim=(0, 2, 3))
    torch.testing.assert_close(module.segmenter[1].running_mean, mean, rtol=1e-5, atol=1e-5)
    assert callback.chosen_domain(module) == domain  # type: ignore[arg-type]


def test_adabn_is_the_target_statistics() -> None:
    target = _images(4, offset=3.0)
    net = _net()
    assert adabn(net, Images(target), images=4, batch_size=2) == 4
    with torch.no_grad():
        mean = net[0](torch.stack(target)).mean(dim=(0, 2, 3))
    torch.testing.assert_close(net[1].running_mean, mean, rtol=1e-5, atol=1e-5)
    with pytest.raises(UssSlamError, match="AdaBN: the target dataset is empty"):
        adabn(net, Images([]))


def test_callback_skips_the_sanity_check_and_checks_arguments() -> None:
    callback = PreciseBatchNorm(Images(_images(2, 1.0)), Images(_images(2, 2.0)), images=2)
    module = SimpleNamespace(adaptation=True, segmenter=_net())
    callback.on_validation_start(SimpleNamespace(sanity_checking=True), module)  # type: ignore[arg-type]
    assert torch.equal(module.segmenter[1].running_mean, torch.zeros(5))
    with pytest.raises(UssSlamError, match="domain"):
        PreciseBatchNorm(Images([]), Images([]), domain="both")  # type: ignore[arg-type]
    with pytest.raises(UssSlamError, match=">= 1"):
        PreciseBatchNorm(Images([]), Images([]), images=0)
    empty = PreciseBatchNorm(Images([]), Images([]), domain="target")
    with pytest.raises(UssSlamError, match="target dataset is empty"):
        empty.on_validation_start(SimpleNamespace(sanity_checking=False), module)  # type: ignore[arg-type]


def test_demo_experiment_reads_the_training_images_of_both_domains(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    cfg = compose_train(["experiment=demo", *data_overrides(uda_data)], tmp_path)
    callback = instantiate(cfg.callbacks.precise_bn)
    # Source statistics for every method: no method's row gains from target statistics alone.
    assert isinstance(callback, PreciseBatchNorm) and callback.domain == "source"
    datamodule = instantiate(cfg.data)
    source, target = callback.datasets["source"], callback.datasets["target"]
    assert len(source) == len(datamodule.source) and len(target) == len(datamodule.target)
    # whole images with the evaluation transform (the fixtures': 160 x 120 and 320 x 240)
    assert tuple(source[0]["image"].shape) == (3, 120, 160)
    assert tuple(target[0]["image"].shape) == (3, 240, 320)
    assert source[0]["image"].dtype == torch.float32 and "label" not in target[0]

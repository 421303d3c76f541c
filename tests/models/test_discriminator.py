"""PatchDiscriminator: layer structure and H / 2**n output sizes."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from uss_slam.models import PatchDiscriminator

torch.set_num_threads(1)


@pytest.mark.parametrize("n_layers", [4, 5, 6, 7])
@pytest.mark.parametrize("size", [(128, 256), (161, 199), (321, 321)])
def test_output_is_input_over_two_to_the_n(n_layers: int, size: tuple[int, int]) -> None:
    d = PatchDiscriminator(in_channels=4, n_layers=n_layers, ndf=8)
    with torch.no_grad():
        out = d(torch.rand(2, 4, *size))
    assert out.shape == (2, 1, size[0] // 2**n_layers, size[1] // 2**n_layers)


@pytest.mark.parametrize("n_layers", [4, 5, 6, 7])
def test_layers_are_strided_4x4_convs_with_leaky_relu(n_layers: int) -> None:
    d = PatchDiscriminator(in_channels=4, n_layers=n_layers)
    convs = [m for m in d.modules() if isinstance(m, nn.Conv2d)]
    acts = [m for m in d.modules() if isinstance(m, nn.LeakyReLU)]
    assert len(convs) == n_layers and len(acts) == n_layers - 1
    assert all(c.kernel_size == (4, 4) and c.stride == (2, 2) for c in convs)
    assert all(a.negative_slope == 0.2 for a in acts)
    assert [c.out_channels for c in convs] == [min(64 * 2**i, 512) for i in range(n_layers - 1)] + [
        1
    ]
    assert convs[0].in_channels == 4
    assert isinstance(list(d.layers)[-1], nn.Conv2d)  # no activation after the last conv


def test_too_small_input_is_a_clear_error() -> None:
    d = PatchDiscriminator(in_channels=4, n_layers=6)
    with pytest.raises(ValueError, match="at least 64×64"):
        d(torch.rand(1, 4, 63, 100))

"""Fully convolutional PatchGAN discriminator of the paper (Fig. 4), as in AdaptSegNet."""

from __future__ import annotations

from typing import Annotated

from torch import Tensor, nn

from uss_slam.core.ranges import Range


class PatchDiscriminator(nn.Module):
    """``n_layers`` stride-2 4×4 convolutions: ``n_layers - 1`` × (conv + LeakyReLU 0.2), then a
    conv to one channel.

    Channels double from ``ndf`` per layer up to ``max_channels``. ``forward`` takes
    ``(N, in_channels, H, W)`` (softmax maps at image size) and returns ``(N, 1, H', W')`` logits
    with ``H' = floor(H / 2**n_layers)``; > 0 means "target domain" (label 1), < 0 "source" (0).
    """

    def __init__(
        self,
        in_channels: Annotated[int, Range(min=1)],
        n_layers: Annotated[int, Range(min=1)] = 5,
        ndf: Annotated[int, Range(min=1)] = 64,
        max_channels: Annotated[int, Range(min=1)] = 512,
    ) -> None:
        super().__init__()  # the values' ranges: the config's schema (uss-train)
        self.n_layers = n_layers
        layers: list[nn.Module] = []
        channels = in_channels
        for index in range(n_layers - 1):
            out = min(ndf * 2**index, max_channels)
            layers += [
                nn.Conv2d(channels, out, kernel_size=4, stride=2, padding=1),
                nn.LeakyReLU(0.2, inplace=True),
            ]
            channels = out
        layers.append(nn.Conv2d(channels, 1, kernel_size=4, stride=2, padding=1))
        self.layers = nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        minimum = 2**self.n_layers
        if x.shape[-2] < minimum or x.shape[-1] < minimum:
            raise ValueError(
                f"a {self.n_layers}-layer discriminator needs inputs of at least "
                f"{minimum}×{minimum} pixels, got {x.shape[-2]}×{x.shape[-1]}"
            )
        return self.layers(x)

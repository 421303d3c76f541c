"""Between the normalised images the networks see and RGB on the 0..1 scale.

The data module hands methods images normalised as every segmenter of this project is trained
and exported: ``(x / 255 − mean) / std`` per RGB channel (:mod:`uss_slam.core.normalization`).
A method that changes images as pictures (colour jitter, blur, a Fourier amplitude swap) goes to
RGB and back with these two functions.
"""

from __future__ import annotations

from collections.abc import Sequence

from torch import Tensor

from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD


def _channels(values: Sequence[float], like: Tensor) -> Tensor:
    return like.new_tensor(tuple(values)).view(1, 3, 1, 1)


def to_rgb(
    images: Tensor,
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> Tensor:
    """``(N, 3, H, W)`` normalised images as RGB on the 0..1 scale (not clamped)."""
    return images * _channels(std, images) + _channels(mean, images)


def from_rgb(
    rgb: Tensor,
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> Tensor:
    """``(N, 3, H, W)`` RGB on the 0..1 scale, normalised as the networks see images."""
    return (rgb - _channels(mean, rgb)) / _channels(std, rgb)

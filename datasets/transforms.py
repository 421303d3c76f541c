"""Joint image / label transforms (torchvision.transforms.v2) for training and evaluation.

Samples are dicts ``{"image": tv_tensors.Image (3, H, W) uint8, "label": tv_tensors.Mask
(H, W) uint8, "name": str}`` (``label`` optional); v2 transforms apply the same geometry to the
image and its mask, bilinear for images and nearest for masks, and pass other entries through.
After the pipeline the image is float32, ImageNet-normalised.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any

import torch
from torchvision import tv_tensors
from torchvision.transforms import v2
from torchvision.transforms.v2 import functional as F

from uss_slam.core.classes import IGNORE_INDEX
from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.core.ranges import Range


class RandomScale(v2.Transform):
    """Resize by a factor drawn uniformly from ``scale_range`` (aspect ratio kept).

    Images are resampled bilinearly with antialiasing, masks with nearest neighbour.
    """

    def __init__(self, scale_range: Sequence[float] = (0.5, 1.5)) -> None:
        super().__init__()
        low, high = (float(v) for v in scale_range)
        if not 0 < low <= high:
            raise ValueError(f"scale_range must satisfy 0 < low <= high, got {scale_range}")
        self.scale_range = (low, high)

    def make_params(self, flat_inputs: list[Any]) -> dict[str, Any]:
        height, width = v2.query_size(flat_inputs)
        low, high = self.scale_range
        scale = low + (high - low) * float(torch.rand(()))
        return {"size": [max(1, round(height * scale)), max(1, round(width * scale))]}

    def transform(self, inpt: Any, params: dict[str, Any]) -> Any:
        return self._call_kernel(F.resize, inpt, params["size"], antialias=True)


def _mean_pixel(mean: Sequence[float]) -> list[int]:
    # Padding with the mean colour makes padded pixels ~0 after normalisation.
    return [round(255 * m) for m in mean]


def _finish(mean: Sequence[float], std: Sequence[float]) -> list[v2.Transform]:
    return [v2.ToDtype(torch.float32, scale=True), v2.Normalize(list(mean), list(std))]


MIN_CROP = 8
"""The smallest crop side, px: the segmenter's output stride (8); a smaller crop leaves its
last layers nothing to convolve."""


def train_transform(
    crop_size: Annotated[int | Sequence[int] | None, Range(min=MIN_CROP)] = 321,
    scale_range: Annotated[Sequence[float] | None, Range(gt=0, length=2)] = (0.5, 1.5),
    hflip: bool = True,
    resize: Sequence[int] | None = None,
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> v2.Compose:
    """Training augmentation: optional fixed ``resize`` ``(H, W)``, random scale, random crop
    (padded with the mean colour / ignore label when the image is smaller), horizontal flip,
    ImageNet normalisation. ``None`` disables a step."""
    steps: list[v2.Transform] = []
    if resize is not None:
        steps.append(v2.Resize(list(resize), antialias=True))
    if scale_range is not None:
        steps.append(RandomScale(scale_range))
    if crop_size is not None:
        size = [crop_size, crop_size] if isinstance(crop_size, int) else list(crop_size)
        fill = {tv_tensors.Image: _mean_pixel(mean), tv_tensors.Mask: IGNORE_INDEX}
        steps.append(v2.RandomCrop(size, pad_if_needed=True, fill=fill))
    if hflip:
        steps.append(v2.RandomHorizontalFlip(p=0.5))
    return v2.Compose(steps + _finish(mean, std))


def eval_transform(
    resize: Sequence[int] | None = None,
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> v2.Compose:
    """Deterministic evaluation transform: optional ``resize`` ``(H, W)``, normalisation."""
    steps: list[v2.Transform] = []
    if resize is not None:
        steps.append(v2.Resize(list(resize), antialias=True))
    return v2.Compose(steps + _finish(mean, std))


def denormalize(
    image: torch.Tensor,
    mean: Sequence[float] = IMAGENET_MEAN,
    std: Sequence[float] = IMAGENET_STD,
) -> torch.Tensor:
    """Normalised ``(3, H, W)`` float image -> ``(H, W, 3)`` uint8 RGB (for logging)."""
    m = torch.tensor(mean, dtype=image.dtype, device=image.device).view(3, 1, 1)
    s = torch.tensor(std, dtype=image.dtype, device=image.device).view(3, 1, 1)
    rgb = (image * s + m).clamp(0, 1).mul(255).round().to(torch.uint8)
    return rgb.permute(1, 2, 0).contiguous()

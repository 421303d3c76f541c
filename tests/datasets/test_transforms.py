"""Joint v2 transforms: geometry applied identically to image and mask, nearest labels, 255 fill."""

from __future__ import annotations

import pytest
import torch
from torchvision import tv_tensors

from uss_slam.core.classes import IGNORE_INDEX
from uss_slam.datasets.transforms import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    RandomScale,
    denormalize,
    eval_transform,
    train_transform,
)

torch.set_num_threads(1)


def _sample(height: int = 60, width: int = 80) -> dict:
    """Vertical class stripes 0..3 (8 px wide); the image encodes the class as grey 60·c."""
    label = (torch.arange(width) // 8 % 4).expand(height, width).to(torch.uint8)
    image = (label * 60).expand(3, height, width).contiguous()
    return {"image": tv_tensors.Image(image), "label": tv_tensors.Mask(label), "name": "x"}


def _decoded_classes(image: torch.Tensor) -> torch.Tensor:
    return (denormalize(image)[..., 0].float() / 60).round().long()


@pytest.mark.parametrize("seed", range(6))
def test_geometry_is_joint_and_labels_stay_class_ids(seed: int) -> None:
    torch.manual_seed(seed)
    transform = train_transform(crop_size=48, scale_range=(0.75, 1.5), hflip=True)
    out = transform(_sample())
    image, label = out["image"], out["label"]
    assert image.shape == (3, 48, 48) and label.shape == (48, 48)
    assert image.dtype == torch.float32 and out["name"] == "x"
    assert set(label.unique().tolist()) <= {0, 1, 2, 3, IGNORE_INDEX}  # nearest: no blends
    # Away from stripe borders, the image's colour says the same class as the label.
    same = _decoded_classes(image) == label.long()
    assert same.float().mean() > 0.75


def test_small_images_are_padded_with_mean_colour_and_ignore() -> None:
    torch.manual_seed(0)
    out = train_transform(crop_size=(80, 100), scale_range=None, hflip=False)(_sample(60, 80))
    label, image = out["label"], out["image"]
    assert label.shape == (80, 100)
    pad = label == IGNORE_INDEX
    assert int(pad.sum()) == 80 * 100 - 60 * 80
    assert image[:, pad].abs().max() < 0.02  # mean colour normalises to ~0


def test_random_scale_resizes_both_and_is_seeded() -> None:
    scale = RandomScale((0.5, 0.5))
    out = scale(_sample(60, 80))
    assert out["image"].shape == (3, 30, 40) and out["label"].shape == (30, 40)
    torch.manual_seed(3)
    a = RandomScale((0.5, 2.0))(_sample())["image"].shape
    torch.manual_seed(3)
    b = RandomScale((0.5, 2.0))(_sample())["image"].shape
    assert a == b
    with pytest.raises(ValueError, match="scale_range"):
        RandomScale((0.0, 1.0))


def test_eval_transform_normalises_and_round_trips() -> None:
    sample = _sample()
    out = eval_transform()(sample)
    torch.testing.assert_close(out["label"], sample["label"])
    expected = (60 * 3 / 255 - IMAGENET_MEAN[0]) / IMAGENET_STD[0]
    assert out["image"][0, 0, 24].item() == pytest.approx(expected, abs=1e-5)
    assert torch.equal(denormalize(out["image"]).permute(2, 0, 1), sample["image"])
    resized = eval_transform(resize=(30, 40))(sample)
    assert resized["image"].shape == (3, 30, 40) and resized["label"].shape == (30, 40)

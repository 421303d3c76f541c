"""Validation reporting: ``val/IoU/<class>`` and ``val/mIoU`` from the module's confusion matrix
(the IoUs from ``uss_slam.core.seg_metrics``) are bit-identical to what torchmetrics'
``MulticlassJaccardIndex`` + ``nanmean`` logged before."""

from __future__ import annotations

import functools
import math

import pytest
import torch
from lightning.pytorch import Trainer
from torchmetrics.classification import MulticlassConfusionMatrix, MulticlassJaccardIndex

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.models import DeepLabV2, PatchDiscriminator
from uss_slam.train.losses import upsample
from uss_slam.train.methods import AdaptSegNet
from uss_slam.train.module import AdversarialSegmentation


def _module() -> AdversarialSegmentation:
    torch.manual_seed(0)
    return AdversarialSegmentation(
        net=DeepLabV2(num_classes=len(CLASS_NAMES), backbone="resnet_small", freeze_bn=True),
        optimizer=functools.partial(torch.optim.SGD, lr=1e-3),
        method=AdaptSegNet(
            discriminator=functools.partial(PatchDiscriminator, len(CLASS_NAMES), 4, 8),
            d_optimizer=functools.partial(torch.optim.Adam, lr=1e-4),
        ),
        max_iters=10,
    )


def _reference(n: int) -> MulticlassJaccardIndex:
    """The previous implementation."""
    return MulticlassJaccardIndex(
        num_classes=n, average="none", ignore_index=IGNORE_INDEX, zero_division=float("nan")
    )


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Bitwise equal float32 scalars (NaN equals NaN)."""
    assert a.dtype == b.dtype == torch.float32
    return (math.isnan(a.item()) and math.isnan(b.item())) or torch.equal(a, b)


@pytest.mark.parametrize("num_classes", [4, 21])
def test_logged_values_equal_the_jaccard_index(num_classes: int) -> None:
    module = _module()
    names = tuple(f"c{k}" for k in range(num_classes))
    module.class_names = names
    module.val_confusion = MulticlassConfusionMatrix(num_classes, ignore_index=IGNORE_INDEX)
    logged: dict[str, torch.Tensor] = {}
    module.log_dict = lambda values, **_: logged.update(values)  # type: ignore[method-assign]
    module.log = lambda name, value, **_: logged.update({name: value})  # type: ignore[method-assign]
    g = torch.Generator().manual_seed(num_classes)
    for trial in range(60):
        logged.clear()
        reference = _reference(num_classes)
        for _ in range(3):
            labels = torch.randint(0, num_classes, (2, 29, 31), generator=g)
            labels[torch.rand(labels.shape, generator=g) < 0.1] = IGNORE_INDEX
            if trial % 2:  # last class absent from truth and prediction: NaN, left out of the mean
                labels[labels == num_classes - 1] = 0
            high = num_classes - trial % 2
            pred = torch.randint(0, high, labels.shape, generator=g)
            right = torch.rand(labels.shape, generator=g) < 0.5  # half the pixels correct
            pred[right] = labels.clamp(max=high - 1)[right]
            module.val_confusion.update(pred, labels)
            reference.update(pred, labels)
        module.on_validation_epoch_end()
        iou = reference.compute()
        assert set(logged) == {f"val/IoU/{n}" for n in names} | {"val/mIoU"}
        for k, name in enumerate(names):
            assert _same(logged[f"val/IoU/{name}"], iou[k]), (trial, name)
        assert _same(logged["val/mIoU"], torch.nanmean(iou)), trial
        assert math.isnan(iou[-1].item()) == bool(trial % 2)


def test_validate_reports_the_segmenters_iou() -> None:
    """Through Lightning: the logged values are those of the segmenter's predictions."""
    module = _module()
    g = torch.Generator().manual_seed(1)
    batches = []
    for _ in range(3):
        labels = torch.randint(0, 3, (2, 33, 41), generator=g)  # no monitor in the truth
        labels[:, :4] = IGNORE_INDEX
        batches.append({"image": torch.randn(2, 3, 33, 41, generator=g), "label": labels})
    trainer = Trainer(
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
    )
    trainer.validate(module, dataloaders=torch.utils.data.DataLoader(batches, batch_size=None))
    logged = trainer.callback_metrics
    reference = _reference(len(CLASS_NAMES))
    module.eval()
    with torch.no_grad():
        for batch in batches:
            logits = upsample(module.segmenter(batch["image"]).main, batch["label"].shape[-2:])
            reference.update(logits.argmax(dim=1), batch["label"])
    iou = reference.compute()
    for k, name in enumerate(CLASS_NAMES):
        assert _same(logged[f"val/IoU/{name}"], iou[k]), name
    assert _same(logged["val/mIoU"], torch.nanmean(iou))

"""model/method=self_training: the DACS / DAFormer iteration against a plain PyTorch loop written
out here, ClassMix and the strong augmentation on known inputs, the teacher in checkpoints (exact
resume) but not in the exported segmenter."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
from hydra.utils import instantiate
from shared_helpers import compose_train
from torch import Tensor
from train_helpers import fit_repeated

from uss_slam.core.errors import UssSlamError
from uss_slam.models import DeepLabV2, PSPNet
from uss_slam.models.checkpoint import read_checkpoint
from uss_slam.testing import reference_step as bench
from uss_slam.train.losses import LossWeights
from uss_slam.train.methods import SelfTraining
from uss_slam.train.methods.self_training import (
    StrongAugmentation,
    class_mix_masks,
    ema_decay,
    iteration_seed,
    rare_class_weights,
)


def _up(logits: Tensor, size: torch.Size) -> Tensor:
    return F.interpolate(logits, size=size, mode="bilinear", align_corners=True)


def _method(net: torch.nn.Module, **kwargs: object) -> SelfTraining:
    return SelfTraining(copy.deepcopy(net), **{"augment": False, **kwargs})  # type: ignore[arg-type]


def _module(batch_domains: bool = True, **kwargs: object):  # noqa: ANN202
    torch.manual_seed(0)
    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8)
    module.method = _method(module.segmenter, **kwargs)
    module.batch_domains = batch_domains
    return module


def _batch(seed: int = 0) -> dict:
    """Two 41-pixel crops per domain; source labels with 3 classes and an ignored band."""
    batch = bench.random_batch(41, 2, seed=seed)
    g = torch.Generator().manual_seed(seed)
    label = torch.randint(0, 3, (2, 41, 41), generator=g)
    label[:, :4] = 255
    batch["source"]["label"] = label
    return batch


def plain_self_training(state, teacher, batch: dict, w: LossWeights, i: int, threshold: float):  # noqa: ANN001, ANN201
    """One DAFormer iteration (no strong augmentation) written out; returns the teacher."""
    seg = state.segmenter
    src, lbl, trg = batch["source"]["image"], batch["source"]["label"], batch["target"]["image"]
    # Teacher: a copy at iteration 0, then alpha * teacher + (1 - alpha) * student.
    if teacher is None:
        teacher = copy.deepcopy(seg)
    else:
        alpha = min(1 - 1 / (i + 1), 0.99)
        with torch.no_grad():
            pairs = zip(teacher.state_dict().values(), seg.state_dict().values(), strict=True)
            for t, s in pairs:
                if t.is_floating_point():
                    t.copy_(alpha * t + (1 - alpha) * s)
                else:
                    t.copy_(s)
    teacher.eval()
    with torch.no_grad():
        prob = F.softmax(_up(teacher(trg).main, trg.shape[-2:]), dim=1)
    confidence, pseudo = prob.max(dim=1)
    pseudo_weight = (confidence > threshold).sum() / confidence.numel()
    # ClassMix: ceil(n/2) of the n labelled classes of each source crop, drawn by randperm.
    gen_state = torch.get_rng_state()
    torch.manual_seed(iteration_seed(0, 0, i))  # the method's seed 0, rank 0
    masks = []
    for label in lbl:
        classes = [c for c in label.unique().tolist() if c != 255]
        chosen = [classes[j] for j in torch.randperm(len(classes))[: math.ceil(len(classes) / 2)]]
        masks.append(sum(label == c for c in chosen).bool())
    torch.set_rng_state(gen_state)
    mask = torch.stack(masks)
    mixed = torch.where(mask[:, None], src, trg)
    mixed_lbl = torch.where(mask, lbl, pseudo)
    weight = torch.where(mask, 1.0, pseudo_weight)

    state.opt_seg.zero_grad()
    out = seg(src)
    loss = w.lambda_seg_aux * F.cross_entropy(
        _up(out.aux, lbl.shape[-2:]), lbl, ignore_index=255
    ) + w.lambda_seg_main * F.cross_entropy(_up(out.main, lbl.shape[-2:]), lbl, ignore_index=255)
    loss.backward()
    out = seg(mixed)
    valid = (mixed_lbl != 255).sum()
    ce_aux = F.cross_entropy(_up(out.aux, lbl.shape[-2:]), mixed_lbl, reduction="none")
    ce_main = F.cross_entropy(_up(out.main, lbl.shape[-2:]), mixed_lbl, reduction="none")
    loss = w.lambda_seg_aux * (ce_aux * weight).sum() + w.lambda_seg_main * (ce_main * weight).sum()
    (loss / valid).backward()
    state.opt_seg.step()
    state.sched_seg.step()
    return teacher


@pytest.mark.parametrize("batch_domains", [True, False])
def test_self_training_matches_plain_pytorch_reference(batch_domains: bool) -> None:
    module = _module(batch_domains, pseudo_threshold=0.3)  # some confident pixels at random init
    state = bench.plain_state_from(module)
    batch = _batch()
    fit_repeated(module, batch, 3)
    teacher = None
    for i in range(3):
        teacher = plain_self_training(state, teacher, batch, module.loss_weights, i, 0.3)
    teacher_mine = module.method.teacher.module
    for mine, ref in ((module.segmenter, state.segmenter), (teacher_mine, teacher)):
        for key, value in mine.state_dict().items():
            torch.testing.assert_close(value, ref.state_dict()[key], rtol=0, atol=1e-6)
    # The teacher trails the student; no discriminator is built.
    assert int(module.method.teacher.n_averaged) == 3
    assert not torch.allclose(
        teacher_mine.main.branches[0].weight, module.segmenter.main.branches[0].weight
    )
    assert module.method.discriminators is None
    # The source pixels counted for rare-class mixing: 3 iterations x the labelled pixels.
    labelled = (batch["source"]["label"] != 255).sum()
    assert float(module.method.class_pixels.sum()) == 3 * float(labelled)


def test_teacher_labels_in_train_mode_with_target_batch_statistics() -> None:
    """DACS / DAFormer: the teacher's BatchNorm normalises with the target batch's statistics and
    dropout is off; only its parameters are averaged."""
    torch.manual_seed(0)
    student = PSPNet(4, "resnet_small", freeze_bn=False)  # trained BatchNorm, dropout 0.1
    with torch.no_grad():  # running statistics far from any batch's
        for m in student.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.fill_(0.5)
                m.running_var.fill_(9.0)
    method = SelfTraining(PSPNet(4, "resnet_small", freeze_bn=False), augment=False)
    method.update_teacher(student)
    method.eval()  # Lightning's validation mode must not leak into the pseudo-labels
    images = torch.randn(2, 3, 33, 33)
    reference = copy.deepcopy(student).train()
    for m in reference.modules():
        if isinstance(m, torch.nn.modules.dropout._DropoutNd):
            m.eval()
    with torch.no_grad():
        expected = _up(reference(images).main, images.shape[-2:])
        eval_mode = _up(copy.deepcopy(student).eval()(images).main, images.shape[-2:])
    logits = method.teacher_logits(images)
    torch.testing.assert_close(logits, expected, rtol=0, atol=1e-6)
    torch.testing.assert_close(method.teacher_logits(images), expected, rtol=0, atol=1e-6)
    assert float((eval_mode - expected).abs().max()) > 1e-3  # the running statistics differ
    # The buffers follow the student (what a frozen BatchNorm would use), not an average.
    method.update_teacher(student)
    for mine, theirs in zip(method.teacher.module.buffers(), student.buffers(), strict=True):
        assert torch.equal(mine, theirs)


def test_class_mix_masks_paste_half_of_the_labelled_classes() -> None:
    torch.manual_seed(0)
    labels = torch.tensor([[0, 0, 1, 1, 2, 255], [3, 3, 3, 3, 255, 255], [255] * 6]).view(3, 2, 3)
    for _ in range(20):
        masks = class_mix_masks(labels)
        assert masks.shape == labels.shape and masks.dtype == torch.bool
        first = set(labels[0][masks[0]].tolist())
        assert len(first) == 2 and first <= {0, 1, 2}  # ceil(3 / 2) of the three classes
        assert masks[0].sum() == sum(int((labels[0] == c).sum()) for c in first)
        assert torch.equal(masks[1], labels[1] == 3)  # one class: ceil(1 / 2) = 1
        assert not masks[2].any()  # nothing labelled, nothing pasted
    # Rare-class weights: a class seen 10 times among a million pixels is pasted, not background.
    weights = rare_class_weights(torch.tensor([1e6, 10.0, 1e5, 1e5], dtype=torch.float64), 0.01)
    torch.testing.assert_close(weights.sum(), torch.tensor(1.0, dtype=torch.float64))
    two = torch.tensor([[0, 0, 1, 1]])
    assert all(set(two[class_mix_masks(two, weights)].tolist()) == {1} for _ in range(20))
    uniform = rare_class_weights(torch.zeros(4, dtype=torch.float64), 0.01)
    assert torch.equal(uniform, torch.full((4,), 0.25, dtype=torch.float64))


def test_strong_augmentation() -> None:
    images = torch.randn(2, 3, 33, 47)
    assert StrongAugmentation.kernel_size(129) == 13 and StrongAugmentation.kernel_size(160) == 15
    assert StrongAugmentation.kernel_size(33) == 3 and StrongAugmentation.kernel_size(5) == 1
    # Never jitter, no blur: the images themselves.
    assert StrongAugmentation(jitter_probability=1.0, blur=False)(images) is images
    # Always jitter, maybe blur: new values, the same for the same seed, each crop its own.
    augment = StrongAugmentation(jitter_probability=0.0)
    torch.manual_seed(3)
    a = augment(images)
    torch.manual_seed(3)
    b = augment(images)
    assert torch.equal(a, b) and a.shape == images.shape and torch.isfinite(a).all()
    assert not torch.allclose(a, images, atol=1e-3)
    same = images[:1].expand(2, -1, -1, -1).clone()
    torch.manual_seed(4)
    out = augment(same)
    assert not torch.allclose(out[0], out[1])


def test_teacher_decay_warms_up_to_alpha() -> None:
    assert [ema_decay(i, 0.99) for i in (0, 1, 3)] == [0.0, 0.5, 0.75]
    assert ema_decay(1000, 0.99) == 0.99


def test_mixing_needs_equal_crops() -> None:
    module = _module()
    batch = _batch()
    batch["target"]["image"] = batch["target"]["image"][:, :, :33, :33]
    with pytest.raises(UssSlamError, match="crop_size alike"):
        fit_repeated(module, batch, 1)


def test_checkpoint_holds_the_teacher_and_resume_is_exact(tmp_path: Path) -> None:
    batch = _batch()
    straight = _module(augment=True)
    fit_repeated(straight, batch, 2, max_epochs=2)

    first = _module(augment=True)
    trainer = fit_repeated(first, batch, 2)
    ckpt = tmp_path / "half.ckpt"
    trainer.save_checkpoint(ckpt)
    resumed = _module(augment=True)
    torch.manual_seed(123)  # another global random state: the iteration's choices do not use it
    fit_repeated(resumed, batch, 2, ckpt_path=ckpt, max_epochs=2)

    assert resumed.iteration == straight.iteration == 4
    for key, value in straight.state_dict().items():
        assert torch.equal(value, resumed.state_dict()[key]), key
    # The checkpoint: the teacher under method.*, the exported segmenter is the student alone.
    info = read_checkpoint(ckpt)
    assert any(k.startswith("method.teacher.module.") for k in info.state_dict)
    assert "method.teacher.n_averaged" in info.state_dict
    student = DeepLabV2(4, "resnet_small")
    student.load_state_dict(info.segmenter_state, strict=True)
    assert torch.equal(
        student.main.branches[0].weight, info.state_dict["segmenter.main.branches.0.weight"]
    )


def test_self_training_config(tmp_path: Path) -> None:
    cfg = compose_train(["experiment=ci", "model/method=self_training", "seed=7"], tmp_path / "r")
    model = instantiate(cfg.model)
    method = model.method
    assert isinstance(method, SelfTraining) and model.hparams["method"] == "self_training"
    assert (method.alpha, method.pseudo_threshold, method.seed) == (0.99, 0.968, 7)
    assert method.augmentation is not None and not method.rare_class_mixing
    # The teacher has the segmenter's architecture (its weights come from the student).
    assert type(method.teacher.module) is type(model.segmenter)
    assert method.teacher.module.state_dict().keys() == model.segmenter.state_dict().keys()
    assert not any(p.requires_grad for p in method.teacher.parameters())
    with pytest.raises(UssSlamError, match="model.method.alpha must be a number in"):
        SelfTraining(model.segmenter, alpha=1.5)
    with pytest.raises(UssSlamError, match="model.method.teacher must build a network"):
        SelfTraining("net")  # type: ignore[arg-type]

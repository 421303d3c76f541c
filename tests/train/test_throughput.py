"""The speed options of AdversarialSegmentation compute what the eager float32 step computes:
``model.compile`` and ``model.channels_last`` to rounding (tight tolerances), the optimiser
kernels (foreach / fused) to rounding, ``trainer.precision=bf16-mixed`` / ``16-mixed`` within a
documented loose tolerance (losses stay float32; the GradScaler path of ``16-mixed`` unscales
before stepping)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.loggers import CSVLogger
from lightning.pytorch.plugins import MixedPrecision
from train_helpers import fit_repeated

from uss_slam.core.errors import UssSlamError
from uss_slam.testing import reference_step as bench
from uss_slam.train.losses import domain_loss, upsample


def _module(**settings: Any):  # -> AdversarialSegmentation
    torch.manual_seed(0)
    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8)
    for name, value in settings.items():
        setattr(module, name, value)
    return module


class Losses(Callback):
    """Each iteration's ``train/*`` scalars and their dtypes (before the module clears them)."""

    def __init__(self) -> None:
        self.values: list[dict[str, float]] = []
        self.dtypes: set[torch.dtype] = set()

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, *_: Any) -> None:
        step, _n = pl_module._step_values
        scalars = pl_module.method.train_scalars(step)
        self.dtypes |= {v.dtype for k, v in scalars.items() if k.startswith("train/loss")}
        self.values.append({k: float(v) for k, v in scalars.items()})


def _fit(module: LightningModule, iters: int, logger: Any = False, **trainer: Any) -> Losses:
    losses = Losses()
    fit_repeated(module, bench.random_batch(41, 2), iters, [losses], logger=logger, **trainer)
    return losses


def _assert_weights_close(mine: LightningModule, ref: LightningModule, seg: float, d: float):
    for name, atol in (("segmenter", seg), ("d_aux", d), ("d_main", d)):
        ours = (mine.segmenter if name == "segmenter" else getattr(mine.method, name)).state_dict()
        theirs = (ref.segmenter if name == "segmenter" else getattr(ref.method, name)).state_dict()
        assert list(ours) == list(theirs)
        for key, value in ours.items():
            torch.testing.assert_close(value, theirs[key], rtol=0, atol=atol, msg=f"{name}.{key}")


def _assert_losses_close(mine: Losses, ref: Losses, rtol: float) -> None:
    assert len(mine.values) == len(ref.values)
    for ours, theirs in zip(mine.values, ref.values, strict=True):
        assert set(ours) == set(theirs)
        for key in theirs:
            if key.startswith("train/loss"):
                assert ours[key] == pytest.approx(theirs[key], rel=rtol), key


# ------------------------------------------------------------------ exact-ish options


@pytest.mark.parametrize("kernels", ["foreach", "fused"])
def test_optimizer_kernels_match_the_default_step(kernels: str) -> None:
    eager, fast = _module(), _module(optimizer_kernels=kernels)
    ref, mine = _fit(eager, 3), _fit(fast, 3)
    opt_seg, opt_d = fast.trainer.optimizers
    for opt in (opt_seg, opt_d):
        assert opt.defaults["fused" if kernels == "fused" else "foreach"] is True
    assert not eager.trainer.optimizers[0].defaults["foreach"]  # torch's CPU default: a loop
    # Same update, other summation order: last-bit differences, magnified by Adam's division by
    # the root of tiny second moments for the discriminators (as in test_step.py).
    _assert_weights_close(fast, eager, seg=1e-6, d=2e-5)
    _assert_losses_close(mine, ref, rtol=1e-6)


def test_fused_falls_back_to_foreach_where_the_optimizer_has_no_fused_kernel() -> None:
    module = _module(optimizer_kernels="fused")
    module.method.d_optimizer_factory = _no_fused(torch.optim.Adamax, lr=1e-4)
    _fit(module, 1)
    opt_seg, opt_d = module.trainer.optimizers
    assert opt_seg.defaults["fused"] is True
    assert opt_d.defaults["foreach"] is True


def _no_fused(cls: type[torch.optim.Optimizer], **options: Any):
    """An optimiser factory whose optimiser takes no ``fused`` argument (TypeError)."""

    def factory(params: Any, **kwargs: Any) -> torch.optim.Optimizer:
        return cls(params, **options, **kwargs)

    return factory


def test_channels_last_matches_the_eager_step() -> None:
    eager, fast = _module(), _module(channels_last=True)
    ref, mine = _fit(eager, 3), _fit(fast, 3)
    assert fast.segmenter.backbone.conv1.weight.is_contiguous(memory_format=torch.channels_last)
    _assert_weights_close(fast, eager, seg=1e-6, d=2e-5)
    _assert_losses_close(mine, ref, rtol=1e-5)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("compile_mode", "fastest", "model.compile_mode must be one of default, reduce-overhead"),
        ("compile_backend", "nope", "model.compile_backend must be one of .*inductor"),
    ],
)
def test_bad_speed_options_name_the_key(key: str, value: str, message: str) -> None:
    import functools

    from uss_slam.models import DeepLabV2, PatchDiscriminator
    from uss_slam.train.methods import AdaptSegNet
    from uss_slam.train.module import AdversarialSegmentation

    with pytest.raises(UssSlamError, match=message):
        AdversarialSegmentation(
            net=DeepLabV2(num_classes=4, backbone="resnet_small"),
            optimizer=functools.partial(torch.optim.SGD, lr=0.1),
            method=AdaptSegNet(
                discriminator=functools.partial(PatchDiscriminator, 4, 3, 8),
                d_optimizer=functools.partial(torch.optim.Adam, lr=0.1),
            ),
            **{key: value},
        )


# ------------------------------------------------------------------ mixed precision


def test_losses_are_float32_under_autocast() -> None:
    logits = torch.randn(2, 4, 6, 6)
    conv = torch.nn.Conv2d(4, 4, 1)
    for dtype in (torch.bfloat16, torch.float16):
        with torch.autocast("cpu", dtype=dtype):
            low = conv(logits)
            assert low.dtype == dtype
            assert upsample(low, (41, 41)).dtype == torch.float32
            assert torch.softmax(upsample(low, (41, 41)), 1).dtype == torch.float32
            assert domain_loss(low, 1.0).dtype == torch.float32


# bf16 keeps 8 bits of mantissa: the convolutions round their inputs and weights to ~0.4%, the
# losses (float32 from float32 logits) land within 1% of full precision and the first steps'
# weights within 1e-3 (segmenter, SGD) / 2e-3 (discriminators, Adam: steps of ~lr = 1e-4 each).
BF16_LOSS_RTOL = 1e-2
BF16_SEG_ATOL = 1e-3
BF16_D_ATOL = 2e-3


def test_bf16_mixed_trains_close_to_float32() -> None:
    eager, bf16 = _module(), _module()
    ref = _fit(eager, 2)
    mine = _fit(bf16, 2, precision="bf16-mixed")
    assert bf16.trainer.precision == "bf16-mixed"
    assert mine.dtypes == {torch.float32}
    _assert_losses_close(mine, ref, rtol=BF16_LOSS_RTOL)
    _assert_weights_close(bf16, eager, seg=BF16_SEG_ATOL, d=BF16_D_ATOL)
    # Not a no-op: the step really ran in reduced precision.
    with pytest.raises(AssertionError):
        _assert_weights_close(bf16, eager, seg=1e-7, d=1e-7)


def test_16_mixed_steps_through_the_grad_scaler() -> None:
    """Lightning turns ``16-mixed`` on CPU into bf16; its MixedPrecision plugin with a
    GradScaler (what a GPU run uses) exercises loss scaling with manual optimisation."""
    eager, fp16 = _module(), _module()
    ref = _fit(eager, 2)
    plugin = MixedPrecision("16-mixed", device="cpu")
    scale = plugin.scaler.get_scale()
    mine = _fit(fp16, 2, plugins=[plugin])
    assert fp16.trainer.precision_plugin is plugin
    assert mine.dtypes == {torch.float32}
    # manual_backward scaled the losses (by 2^16) and each optimiser step unscaled the
    # gradients first: an unscaled step would be 65536x too large for the SGD segmenter.
    assert plugin.scaler.get_scale() == scale  # no overflow, no skipped step
    _assert_losses_close(mine, ref, rtol=BF16_LOSS_RTOL)
    _assert_weights_close(fp16, eager, seg=BF16_SEG_ATOL, d=BF16_D_ATOL)


# ------------------------------------------------------------------ compile


@pytest.mark.slow  # inductor compiles the networks' forward and backward: minutes on 2 cores
def test_compiled_step_matches_eager_and_logs_its_compile_time(tmp_path: Path) -> None:
    eager, compiled = _module(), _module(compile_networks=True)
    start = copy.deepcopy(compiled.state_dict())
    ref = _fit(eager, 3)
    mine = _fit(compiled, 3, logger=CSVLogger(tmp_path, name="", version=""))
    # Compiled in place: the same parameter names (checkpoints and exports unchanged).
    assert list(compiled.state_dict()) == list(start)
    _assert_weights_close(compiled, eager, seg=1e-6, d=2e-5)
    _assert_losses_close(mine, ref, rtol=1e-5)
    assert compiled.compile_seconds is not None and compiled.compile_seconds > 0
    metrics = (tmp_path / "metrics.csv").read_text().splitlines()
    header = metrics[0].split(",")
    rows = [dict(zip(header, line.split(","), strict=True)) for line in metrics[1:]]
    logged = [float(r["train/compile_s"]) for r in rows if r.get("train/compile_s")]
    assert logged == [pytest.approx(compiled.compile_seconds)]

"""One training iteration of AdversarialSegmentation = Algorithm 1, checked structurally and
against the independent plain-PyTorch reference of uss_slam.testing.reference_step."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from train_helpers import ADVERSARIAL_SCALARS, assert_weights_match_reference, fit_repeated

from uss_slam.testing import reference_step as bench
from uss_slam.train.methods import SourceOnly, frozen
from uss_slam.train.module import AdversarialSegmentation


def _module(
    adaptation: bool = True, batch_domains: bool = True, channels_last: bool = False
) -> AdversarialSegmentation:
    torch.manual_seed(0)
    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8)
    if not adaptation:
        module.method = SourceOnly()
    module.batch_domains = batch_domains
    module.channels_last = channels_last
    return module


def _params(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


class Probe(Callback):
    """Records gradients and weights at each optimiser step of the first iteration."""

    def __init__(self) -> None:
        self.steps: list[dict[str, Any]] = []
        self.after: dict[str, dict[str, torch.Tensor]] = {}
        self.segmenter_forwards = 0

    def on_fit_start(self, trainer: Trainer, pl_module: LightningModule) -> None:
        def count(*_: object) -> None:
            self.segmenter_forwards += 1

        pl_module.segmenter.register_forward_hook(count)

    def on_before_optimizer_step(
        self, trainer: Trainer, pl_module: LightningModule, optimizer: torch.optim.Optimizer
    ) -> None:
        discriminators = pl_module.method.discriminators or ()
        self.steps.append(
            {
                "optimizer": trainer.optimizers.index(optimizer),
                "d_grads": [p.grad is not None for d in discriminators for p in d.parameters()],
                "seg_grads": [
                    p.grad is not None for p in pl_module.segmenter.parameters() if p.requires_grad
                ],
                "segmenter": _params(pl_module.segmenter),
                "discriminators": _params(discriminators[-1]) if discriminators else {},
            }
        )

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, *_: Any) -> None:
        if not self.after:
            discriminators = pl_module.method.discriminators or ()
            self.after = {
                "segmenter": _params(pl_module.segmenter),
                "discriminators": _params(discriminators[-1]) if discriminators else {},
            }


def _equal(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("batch_domains", [True, False])
def test_segmenter_step_leaves_discriminators_without_gradients(batch_domains: bool) -> None:
    module = _module(batch_domains=batch_domains)
    before = {
        "segmenter": _params(module.segmenter),
        "discriminators": _params(module.method.d_main),
    }
    bn_before = module.segmenter.backbone.bn1.running_mean.clone()
    probe = Probe()
    fit_repeated(module, bench.random_batch(41, 2), 1, [probe])

    seg_step, d_step = probe.steps
    assert (seg_step["optimizer"], d_step["optimizer"]) == (0, 1)
    assert not any(seg_step["d_grads"])  # D frozen while L_seg and L_adv flow back
    assert all(seg_step["seg_grads"]) and len(seg_step["seg_grads"]) > 0
    assert all(d_step["d_grads"])
    # The segmenter step changed the segmenter only; the D step changed the discriminators only.
    assert not _equal(d_step["segmenter"], before["segmenter"])
    assert _equal(d_step["discriminators"], before["discriminators"])
    assert _equal(probe.after["segmenter"], d_step["segmenter"])
    assert not _equal(probe.after["discriminators"], d_step["discriminators"])
    # Source and target: one batched forward (frozen BN) or one forward each.
    assert probe.segmenter_forwards == (1 if batch_domains else 2)
    # Frozen BatchNorm: statistics never move.
    assert torch.equal(module.segmenter.backbone.bn1.running_mean, bn_before)
    assert module.iteration == 1


@pytest.mark.parametrize(
    ("adaptation", "batch_domains", "channels_last"),
    [(True, True, False), (True, False, False), (True, True, True), (False, True, False)],
)
def test_module_matches_plain_pytorch_reference(
    adaptation: bool, batch_domains: bool, channels_last: bool
) -> None:
    module = _module(adaptation, batch_domains, channels_last)
    state = bench.plain_state_from(module)
    batch = bench.random_batch(41, 2)
    fit_repeated(module, batch, 3)
    for _ in range(3):
        bench.plain_iteration(state, batch, bench.weights_of(module), adaptation=adaptation)
    assert_weights_match_reference(module, state)
    lrs = [g["lr"] for g in module.trainer.optimizers[0].param_groups]
    assert lrs == [g["lr"] for g in state.opt_seg.param_groups]
    assert lrs[1] == pytest.approx(10 * lrs[0])


def test_source_only_trains_the_segmenter_only() -> None:
    module = _module(adaptation=False)
    probe = Probe()
    fit_repeated(module, bench.random_batch(41, 2), 2, [probe])
    assert [s["optimizer"] for s in probe.steps] == [0, 0]  # only the segmenter steps
    assert probe.segmenter_forwards == 2  # source only, two iterations
    assert module.method.discriminators is None and len(module.trainer.optimizers) == 1
    assert module.iteration == 2


def test_non_finite_loss_stops_before_the_step() -> None:
    module = _module()
    with torch.no_grad():
        module.segmenter.main.branches[0].bias.fill_(float("nan"))
    before = _params(module.segmenter)
    from uss_slam.train.module import NonFiniteLossError

    with pytest.raises(NonFiniteLossError, match="non-finite loss_seg_src_main .* iteration 0"):
        fit_repeated(module, bench.random_batch(41, 1), 1)
    after = _params(module.segmenter)
    assert all(torch.equal(before[k], after[k]) for k in before if "main.branches.0" not in k)
    # The discriminators were frozen when the error was raised; they are trainable again.
    assert all(
        p.requires_grad for d in (module.method.d_aux, module.method.d_main) for p in d.parameters()
    )


class StepValues(Callback):
    """The module's detached per-step values, read before the module logs them."""

    def __init__(self) -> None:
        self.scalars: list[dict[str, float]] = []
        self.d_requires_grad: list[bool] = []

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, *_: Any) -> None:
        step, _n = pl_module._step_values
        self.scalars.append({k: float(v) for k, v in pl_module._train_scalars(step).items()})
        self.d_requires_grad.append(
            all(
                p.requires_grad
                for d in (pl_module.method.discriminators or ())
                for p in d.parameters()
            )
        )


@pytest.mark.parametrize("adaptation", [True, False])
def test_scalars_reach_tensorboard_on_logging_steps_only(adaptation: bool, tmp_path: Path) -> None:
    from lightning.pytorch.loggers import TensorBoardLogger
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    module = _module(adaptation=adaptation)
    module.max_iters = 7
    probe = StepValues()
    logged_names: list[str] = []
    log = module.log

    def counting_log(name: str, *args: Any, **kwargs: Any) -> None:
        logged_names.append(name)
        log(name, *args, **kwargs)

    module.log = counting_log  # log_dict goes through it too
    trainer = fit_repeated(
        module,
        bench.random_batch(41, 2),
        7,
        [probe],
        logger=TensorBoardLogger(tmp_path, name="", version=""),
        log_every_n_steps=3,
    )
    events = EventAccumulator(str(tmp_path), size_guidance={"scalars": 0})
    events.Reload()
    expected = ADVERSARIAL_SCALARS if adaptation else {k for k in ADVERSARIAL_SCALARS if "seg" in k}
    assert {k for k in events.Tags()["scalars"] if k.startswith("train/")} == expected
    assert len(probe.scalars) == 7
    assert all(probe.d_requires_grad)  # frozen only inside the segmenter step
    for key in expected:
        points = events.Scalars(key)
        # Every 3rd step (x axis = iterations from 0) and the step that stops training, each
        # with that step's own value, not one left over from an earlier step.
        assert [p.step for p in points] == [2, 5, 6]
        for point in points:
            assert point.value == pytest.approx(probe.scalars[point.step][key], rel=1e-6)
    assert trainer.callback_metrics["iteration"] == 7
    # The train/* scalars cost Lightning bookkeeping only on the 3 steps that write them.
    assert sorted(n for n in logged_names if n.startswith("train/")) == sorted(3 * list(expected))
    assert logged_names.count("iteration") == 7  # progress bar and checkpoint names: every step
    accuracies = [s[k] for s in probe.scalars for k in s if "d_acc" in k]
    assert all(0.0 <= a <= 1.0 for a in accuracies)


def test_discriminators_frozen_restores_on_error() -> None:
    module = _module()
    # A user-frozen parameter stays frozen.
    module.method.d_main.layers[0].weight.requires_grad_(False)
    with pytest.raises(RuntimeError, match="inside"), frozen(*module.method.discriminators):
        assert not any(
            p.requires_grad
            for d in (module.method.d_aux, module.method.d_main)
            for p in d.parameters()
        )
        assert all(p.requires_grad for p in module.segmenter.heads().parameters())
        raise RuntimeError("inside")
    assert not module.method.d_main.layers[0].weight.requires_grad
    rest = [p for d in (module.method.d_aux, module.method.d_main) for p in d.parameters()]
    assert sum(not p.requires_grad for p in rest) == 1


@pytest.mark.parametrize("mode", ["separate", "joint", "running"])
def test_trained_batch_norm_matches_plain_reference_in_every_domain_mode(mode: str) -> None:
    """BatchNorm in train mode: ``separate`` normalises each domain's batch alone (two
    forwards), ``joint`` both batches together (one forward), ``running`` the target batch by
    the running statistics: each as its plain reference."""
    torch.manual_seed(0)
    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8, freeze_bn=False)
    module.domain_batch_norm = mode
    state = bench.plain_state_from(module)
    bn = module.segmenter.backbone.bn1
    seen: list[tuple[int, bool]] = []
    bn.register_forward_pre_hook(lambda m, x: seen.append((len(x[0]), m.training)))
    batch = bench.random_batch(41, 2)
    fit_repeated(module, batch, 2)
    for _ in range(2):
        bench.plain_iteration(state, batch, bench.weights_of(module), domain_batch_norm=mode)
    assert_weights_match_reference(module, state)
    # what the first BatchNorm saw per iteration: (crops, batch statistics?)
    expected = {
        "separate": [(2, True), (2, True)],
        "joint": [(4, True)],
        "running": [(2, True), (2, False)],
    }[mode]
    assert seen == expected * 2
    assert bn.training  # train mode again after the running-statistics forward
    assert torch.allclose(bn.running_mean, state.segmenter.backbone.bn1.running_mean, atol=1e-6)
    assert torch.allclose(bn.running_var, state.segmenter.backbone.bn1.running_var, atol=1e-6)


def test_joint_batch_norm_needs_crops_of_one_size() -> None:
    from uss_slam.core.errors import UssSlamError
    from uss_slam.train.methods import can_batch_domains

    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8, freeze_bn=False)
    module.domain_batch_norm = "joint"
    src, trg = torch.zeros(2, 3, 41, 41), torch.zeros(2, 3, 33, 41)
    with pytest.raises(UssSlamError, match=r"domain_batch_norm=joint .* \(41, 41\) and \(33, 41\)"):
        can_batch_domains(module, src, trg)
    module.domain_batch_norm = "separate"
    assert not can_batch_domains(module, src, trg)


@pytest.mark.parametrize(
    ("key", "value", "line"),
    [
        ("domain_batch_norm", "x",
         "model.domain_batch_norm: expected one of 'separate', 'joint', 'running', got 'x'"),
        ("optimizer_kernels", "turbo",
         "model.optimizer_kernels: expected one of 'default', 'foreach', 'fused', got 'turbo'"),
        ("max_iters", 0, "model.max_iters: expected an integer >= 1, got 0"),
        ("poly_power", -1, "model.poly_power: expected a number > 0, got -1"),
        ("poly_total_iters", 0, "model.poly_total_iters: expected an integer >= 1 or null, got 0"),
        ("head_lr_mult", 0, "model.head_lr_mult: expected a number > 0, got 0"),
    ],
)  # fmt: skip
def test_the_schema_of_the_module_refuses_values_out_of_range(
    key: str, value: object, line: str
) -> None:
    """What uss-train checks before building anything (the module's annotated ranges)."""
    from omegaconf import OmegaConf

    from uss_slam.core.schema import SchemaError, check_target

    node = OmegaConf.create({"_target_": "uss_slam.train.module.AdversarialSegmentation"})
    node[key] = value
    with pytest.raises(SchemaError) as info:
        check_target(node, "model")
    assert str(info.value) == line


def test_reference_batch_norm_matches_a_plain_restatement_of_adaptsegnet() -> None:
    """``model.net.batchnorm=reference`` against AdaptSegNet's / ADVENT's set-up written out in
    plain PyTorch: ``model.train()``, ``requires_grad=False`` on every BatchNorm's affine terms,
    source forward then target forward (each normalised by its own batch, both updating the
    running statistics): after one iteration the same weights and running statistics."""
    from torch import nn

    from uss_slam.models.deeplab import DeepLabV2

    torch.manual_seed(0)
    module = bench.build_module("resnet_small", max_iters=10, n_layers=5, ndf=8, freeze_bn=False)
    plain_module = copy.deepcopy(module)
    net = DeepLabV2(4, "resnet_small", batchnorm="reference")
    net.load_state_dict(module.segmenter.state_dict())
    module.segmenter = net
    # The reference code's set-up, independent of model.net.batchnorm:
    plain_module.segmenter.train()
    for m in plain_module.segmenter.modules():
        if isinstance(m, nn.BatchNorm2d):
            for p in m.parameters():
                p.requires_grad = False
    state = bench.plain_state_from(plain_module)  # its SGD holds what requires grad
    start = _params(net)
    seen: list[tuple[int, bool]] = []
    net.backbone.bn1.register_forward_pre_hook(lambda m, x: seen.append((len(x[0]), m.training)))
    batch = bench.random_batch(41, 2)
    fit_repeated(module, batch, 1)
    bench.plain_iteration(state, batch, bench.weights_of(module), domain_batch_norm="separate")
    assert_weights_match_reference(module, state)  # parameters and running statistics
    assert seen == [(2, True), (2, True)]  # source, then target: batch statistics each
    after = _params(net)
    bn_keys = [k for k in after if ".bn" in k or "downsample.1" in k]
    for key in bn_keys:
        if key.endswith(("weight", "bias")):
            assert torch.equal(after[key], start[key]), key  # affine frozen
        elif key.endswith("running_mean"):
            assert not torch.equal(after[key], start[key]), key  # statistics fed
        elif key.endswith("num_batches_tracked"):
            assert after[key].item() == 2, key  # by both forwards


def test_reference_batch_norm_needs_separate_domain_forwards() -> None:
    import functools

    from uss_slam.core.errors import UssSlamError
    from uss_slam.models.deeplab import DeepLabV2

    for mode in ("joint", "running"):
        with pytest.raises(
            UssSlamError,
            match=f"^model.domain_batch_norm={mode} contradicts model.net.batchnorm=reference",
        ):
            AdversarialSegmentation(
                net=DeepLabV2(4, "resnet_small", batchnorm="reference"),
                optimizer=functools.partial(torch.optim.SGD, lr=0.1),
                method=SourceOnly(),
                domain_batch_norm=mode,
            )


@pytest.mark.parametrize("mode", ["trained", "reference"])
def test_precise_batch_norm_keeps_the_reference_statistics(mode: str) -> None:
    from types import SimpleNamespace

    from uss_slam.models.deeplab import DeepLabV2
    from uss_slam.train.precise_bn import PreciseBatchNorm

    torch.manual_seed(0)
    images = [{"image": torch.randn(3, 33, 33) * 2 + 1} for _ in range(4)]
    net = DeepLabV2(4, "resnet_small", batchnorm=mode)
    before = net.backbone.bn1.running_mean.clone()
    callback = PreciseBatchNorm(images, images, images=4, batch_size=2)  # type: ignore[arg-type]
    trainer = SimpleNamespace(sanity_checking=False)
    callback.on_validation_start(trainer, SimpleNamespace(segmenter=net))  # type: ignore[arg-type]
    kept = torch.equal(before, net.backbone.bn1.running_mean)
    assert kept is (mode == "reference")

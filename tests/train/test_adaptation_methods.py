"""Adaptation methods as a config group: the shipped choices, the deprecated flag, the shared
two-domain pass, and a new method added in one class + one yaml file."""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import ClassVar

import pytest
import torch
import torch.nn.functional as F
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import ConfigCompositionException
from hydra.utils import instantiate
from shared_helpers import CONFIG_DIR, compose_train, data_overrides
from torch import Tensor, nn
from train_helpers import fit_repeated, quiet_trainer

from uss_slam.core.errors import UssSlamError
from uss_slam.models.checkpoint import read_checkpoint
from uss_slam.testing import reference_step as bench
from uss_slam.train import method_configs
from uss_slam.train.losses import upsample
from uss_slam.train.method_configs import (
    METHOD_GROUP,
    method_class,
    method_names,
    method_target,
    trains_discriminators,
)
from uss_slam.train.methods import (
    AdaptSegNet,
    DomainPass,
    Method,
    SourceOnly,
    SourceSegmentation,
    StepValues,
    TrainBatch,
    can_batch_domains,
    segmenter_step,
)
from uss_slam.train.module import AdversarialSegmentation
from uss_slam.train.train import check_architecture, train


class TargetEntropy(Method):
    """A toy method (MinEnt-like): segmentation loss on source + ``weight`` × the mean entropy of
    the target's main-head softmax; no discriminators."""

    name: ClassVar[str] = "target_entropy"
    adapts: ClassVar[bool] = True
    trains_discriminators: ClassVar[bool] = False

    def __init__(self, weight: float = 1.0) -> None:
        super().__init__()
        self.weight = weight

    def training_step(self, module: AdversarialSegmentation, batch: TrainBatch) -> StepValues:
        opt_seg = module.segmenter_optimizer()
        opt_seg.zero_grad()
        src_img, trg_img = batch["source"]["image"], batch["target"]["image"]
        batched = can_batch_domains(module, src_img, trg_img)
        with DomainPass(module.segmenter, src_img, trg_img, module.manual_backward, batched) as p:
            src = SourceSegmentation(
                p.source(), batch["source"]["label"], module.loss_weights, module.iteration
            )
            p.backward(src.loss)
            logp = F.log_softmax(upsample(p.target().main, trg_img.shape[-2:]), dim=1)
            entropy = -(logp.exp() * logp).sum(dim=1).mean()
            p.backward(self.weight * entropy)
        opt_seg.step()
        return {**src.values, "loss_ent_trg_main": entropy.detach()}


def _compose(tmp_path: Path, *overrides: str):
    return compose_train(["experiment=ci", *overrides], tmp_path / "run")


@pytest.mark.parametrize(
    ("overrides", "kind"),
    [
        ([], AdaptSegNet),
        (["model/method=adaptsegnet"], AdaptSegNet),
        (["model/method=source_only"], SourceOnly),
        (["model=source_only"], SourceOnly),
    ],
)
def test_method_config_group(overrides: list[str], kind: type, tmp_path: Path) -> None:
    model = instantiate(_compose(tmp_path, *overrides).model)
    assert type(model.method) is kind
    assert model.adaptation is kind.adapts
    assert model.hparams["method"] == kind.name and model.hparams["adaptation"] is kind.adapts


@pytest.mark.parametrize("method", method_names())
def test_a_method_owns_what_it_trains(method: str, tmp_path: Path) -> None:
    """Every option of ``model/method`` (a new one too): its class is the config's, and the
    discriminators and their optimiser exist only for a method whose class trains them."""
    model = instantiate(_compose(tmp_path, f"model/method={method}").model)
    assert type(model.method) is method_class(method) and model.method.name == method
    trains = method_class(method).trains_discriminators
    own = {"method"} if model.method.state_dict() else set()  # e.g. a teacher, discriminators
    assert {key.split(".")[0] for key in model.state_dict()} == {"segmenter"} | own
    children = {key.split(".")[1] for key in model.state_dict() if key.startswith("method.")}
    assert ({"d_aux", "d_main"} <= children) is trains
    optimizers, schedules = model.configure_optimizers()
    assert len(optimizers) == len(schedules) == (2 if trains else 1)
    assert (model.method.discriminators is not None) is trains


def test_the_shipped_methods_are_the_config_group() -> None:
    shipped = sorted(p.stem for p in METHOD_GROUP.glob("*.yaml"))
    assert sorted(method_names()) == shipped and method_names()[0] == "source_only"
    trains = {m for m in method_names() if trains_discriminators(m)}
    assert trains == {"adaptsegnet", "advent"}  # the shipped classes' own flag
    for method in method_names():  # read from the sources without torch: as the classes say
        read = method_configs._class_constant(method_target(method), "trains_discriminators")
        assert read is method_class(method).trains_discriminators


def test_the_method_is_chosen_by_its_config_group_only(tmp_path: Path) -> None:
    """There is no ``model.adaptation`` flag: ``model/method`` alone says what is trained."""
    with pytest.raises(ConfigCompositionException, match="model.adaptation"):
        _compose(tmp_path, "model.adaptation=false")
    assert isinstance(instantiate(_compose(tmp_path, "model=source_only").model).method, SourceOnly)
    assert isinstance(instantiate(_compose(tmp_path).model).method, AdaptSegNet)


def test_method_must_be_a_method(tmp_path: Path) -> None:
    cfg = _compose(tmp_path, "model.method._target_=torch.nn.Identity")
    with pytest.raises(Exception) as info:
        instantiate(cfg.model)
    assert isinstance(info.value.__cause__ or info.value, UssSlamError)
    assert "model.method must be an adaptation method" in str(info.value)


# --------------------------------------------------------------------------- checkpoints


def _resume(module: AdversarialSegmentation, batch: dict, ckpt: Path | None, root: Path) -> None:
    """Two iterations (one epoch) of ``module`` on ``batch``, resumed from ``ckpt`` if given."""
    fit_repeated(
        module, batch, 2, ckpt_path=ckpt, max_epochs=2 if ckpt else 1, default_root_dir=root
    )


def _source_only_module() -> AdversarialSegmentation:
    """A source-only module as the config builds it now: no discriminators."""
    net = bench.build_module("resnet_small", max_iters=4).segmenter
    return AdversarialSegmentation(
        net=net,
        optimizer=functools.partial(torch.optim.SGD, lr=2.5e-4, momentum=0.9, nesterov=True),
        method=SourceOnly(),
        max_iters=4,
    )


def test_checkpoints_with_unused_discriminators_still_resume(tmp_path: Path) -> None:
    """Source-only runs used to build (and save) two discriminators and their optimiser: their
    checkpoints resume into a module without them and continue exactly."""
    torch.manual_seed(0)
    old = bench.build_module("resnet_small", max_iters=4, n_layers=4, ndf=8)
    old.optimizer_factory = functools.partial(
        torch.optim.SGD, lr=2.5e-4, momentum=0.9, nesterov=True
    )
    # The earlier layout: the module built discriminators (d_aux.*, d_main.*) and their
    # optimiser for every method, source-only included.
    old.method.training_step = lambda module, batch: segmenter_step(module, batch["source"]).values
    old.method.train_scalars = functools.partial(Method.train_scalars, old.method)
    batch = bench.random_batch(33, 2)
    _resume(old, batch, None, tmp_path)
    ckpt = tmp_path / "old.ckpt"
    old.trainer.save_checkpoint(ckpt)
    saved = torch.load(ckpt, weights_only=True)
    saved["state_dict"] = {k.removeprefix("method."): v for k, v in saved["state_dict"].items()}
    saved["hyper_parameters"]["method"] = "source_only"
    del saved["hyper_parameters"]["method_settings"]
    torch.save(saved, ckpt)
    assert any(k.startswith("d_main.") for k in saved["state_dict"])
    assert len(saved["optimizer_states"]) == len(saved["lr_schedulers"]) == 2

    new = _source_only_module()
    assert new.method.discriminators is None
    check_architecture(new, read_checkpoint(ckpt))  # uss-train's check before resuming
    _resume(new, batch, ckpt, tmp_path)
    _resume(old, batch, ckpt, tmp_path)  # the reference: the old layout resumed
    assert new.iteration == old.iteration == 4
    for key, value in new.segmenter.state_dict().items():
        # Equal only if the weights and the SGD momentum were restored.
        torch.testing.assert_close(value, old.segmenter.state_dict()[key], rtol=0, atol=0)
    assert new.lr_schedulers().last_epoch == 4


def test_a_checkpoint_without_discriminators_does_not_resume_an_adversarial_run(
    tmp_path: Path,
) -> None:
    torch.manual_seed(0)
    batch = bench.random_batch(33, 2)
    source_only = _source_only_module()
    _resume(source_only, batch, None, tmp_path)
    ckpt = tmp_path / "source_only.ckpt"
    source_only.trainer.save_checkpoint(ckpt)
    adversarial = bench.build_module("resnet_small", max_iters=4, n_layers=4, ndf=8)
    with pytest.raises(UssSlamError, match="model/method=source_only has no discriminators"):
        check_architecture(adversarial, read_checkpoint(ckpt))
    with pytest.raises(UssSlamError, match="model/method=source_only has no discriminators"):
        _resume(adversarial, batch, ckpt, tmp_path)


# --------------------------------------------------------------------------- DomainPass


class _Net(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 4, 3)
        self.forwards: list[int] = []

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        self.forwards.append(x.shape[0])
        y = self.conv(x)
        return y, 2 * y


@pytest.mark.parametrize("batched", [True, False])
def test_domain_pass_batched_and_unbatched_give_the_same_gradients(batched: bool) -> None:
    torch.manual_seed(0)
    net = _Net()
    src, trg = torch.randn(2, 3, 9, 9), torch.randn(3, 3, 9, 9)
    backwards: list[float] = []

    def backward(loss: Tensor) -> None:
        backwards.append(float(loss))
        loss.backward()

    with DomainPass(net, src, trg, backward, batched) as p:
        out_src = p.source()
        assert backwards == [] and out_src[0].shape[0] == 2
        p.backward(out_src[0].square().mean())
        out_trg = p.target()
        assert out_trg[1].shape[0] == 3 and type(out_trg) is tuple
        p.backward(out_trg[1].abs().mean())
        assert len(backwards) == (0 if batched else 2)
    assert len(backwards) == 1 if batched else 2
    assert net.forwards == ([5] if batched else [2, 3])

    ref = copy.deepcopy(net)
    ref.zero_grad()
    (ref(src)[0].square().mean() + ref(trg)[1].abs().mean()).backward()
    for mine, theirs in zip(net.parameters(), ref.parameters(), strict=True):
        torch.testing.assert_close(mine.grad, theirs.grad, rtol=1e-6, atol=1e-7)


def test_domain_pass_error_skips_the_pending_backward() -> None:
    net = _Net()
    calls: list[Tensor] = []
    with (
        pytest.raises(RuntimeError, match="stop"),
        DomainPass(net, torch.randn(1, 3, 5, 5), torch.randn(1, 3, 5, 5), calls.append, True) as p,
    ):
        p.backward(p.source()[0].sum())
        raise RuntimeError("stop")
    assert calls == []
    with DomainPass(net, torch.randn(1, 3, 5, 5), None, calls.append, True) as p:
        p.backward(p.source()[0].sum())
        assert len(calls) == 1  # no target: unbatched
        with pytest.raises(ValueError, match="no target input"):
            p.target()


# --------------------------------------------------------------------------- a new method


TOY_CONFIG = "_target_: test_adaptation_methods.TargetEntropy\nweight: 0.5\n"


def test_a_new_method_joins_the_method_list(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """One more ``model/method/<name>.yaml`` in the group is one more method for the grid and
    the every-method tests (nothing else lists them); a YAML without a ``_target_`` is an error
    naming the file."""
    group = tmp_path / "method"
    group.mkdir()
    for path in METHOD_GROUP.glob("*.yaml"):
        (group / path.name).write_text(path.read_text())
    (group / "target_entropy.yaml").write_text(TOY_CONFIG)
    monkeypatch.setattr(method_configs, "METHOD_GROUP", group)
    method_configs.method_target.cache_clear()
    try:
        assert method_names() == ("source_only", *sorted([*method_names()[1:]]))
        assert "target_entropy" in method_names()
        assert method_class("target_entropy") is TargetEntropy
        assert not trains_discriminators("target_entropy")
        (group / "broken.yaml").write_text("weight: 0.5\n")
        with pytest.raises(UssSlamError, match="broken.yaml.*expected a _target_"):
            method_class("broken")
        with pytest.raises(UssSlamError, match="model/method=nope: no such method"):
            method_class("nope")
    finally:
        method_configs.method_target.cache_clear()


def test_a_new_method_plugs_in_by_config(uda_data: dict[str, Path], tmp_path: Path) -> None:
    """One class (above) + one ``model/method/<name>.yaml``: chosen on the command line."""
    configs = tmp_path / "configs"
    (configs / "model" / "method").mkdir(parents=True)
    (configs / "model" / "method" / "target_entropy.yaml").write_text(TOY_CONFIG)
    overrides = [
        f"hydra.searchpath=[file://{configs}]",
        "model/method=target_entropy",
        *data_overrides(uda_data),
        "logger=none",
    ]
    cfg = _compose(tmp_path, *overrides)
    model = instantiate(cfg.model)
    assert isinstance(model.method, TargetEntropy) and model.method.weight == 0.5

    # Two iterations through the module: the segmenter learns (no discriminators are built),
    # the toy's own value is what gets logged.
    assert model.method.discriminators is None
    seg_before = copy.deepcopy(model.segmenter.state_dict())
    datamodule = instantiate(cfg.data)
    trainer = quiet_trainer(limit_val_batches=0)
    trainer.fit(model, datamodule=datamodule)
    assert model.iteration == cfg.data.iterations_per_epoch == 2
    assert not all(torch.equal(v, seg_before[k]) for k, v in model.segmenter.state_dict().items())
    (opt_seg,) = trainer.optimizers
    assert len(opt_seg.state) > 0
    (sched_seg,) = (c.scheduler for c in trainer.lr_scheduler_configs)
    assert sched_seg.last_epoch == 2

    # The same through uss-train's glue, logged keys included.
    metrics = train(_compose(tmp_path, *overrides, "+trainer.fast_dev_run=true"))
    assert {"train/loss_seg_src_main", "train/loss_ent_trg_main"} <= set(metrics)
    assert not any(k.startswith(("train/loss_adv", "train/loss_d")) for k in metrics)


@pytest.mark.parametrize(
    ("override", "new"),
    [
        ("+model.discriminator.n_layers=4", "model.method.discriminator"),
        ("+model.d_optimizer.lr=0.1", "model.method.d_optimizer"),
        ("+model.loss.lambda_adv_main=0.1", "model.method.lambda_adv_main"),
    ],
)
def test_a_key_of_an_earlier_version_names_where_it_moved(
    override: str, new: str, tmp_path: Path
) -> None:
    from uss_slam.train.train import check_moved_keys

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=["experiment=ci", override])
    with pytest.raises(UssSlamError, match=f"moved to {new} "):
        check_moved_keys(cfg)
    check_moved_keys(_compose(tmp_path))


def test_another_methods_setting_is_dropped_with_a_warning_and_a_typo_refused(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from uss_slam.train.method_configs import unused_method_settings

    def raw(*overrides: str):  # composed without uss-train's pruning
        GlobalHydra.instance().clear()
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
            return compose("train", overrides=["experiment=ci", *overrides])

    cfg = raw("model/method=minent", "+model.method.lambda_adv_main=0.1")
    with caplog.at_level("WARNING"):
        assert unused_method_settings(cfg.model.method) == ["discriminator", "lambda_adv_main"]
    assert "model.method.lambda_adv_main: model/method=minent has no such setting" in caplog.text
    cfg = raw("model/method=minent", "+model.method.lamda_ent_main=0.1")
    with pytest.raises(UssSlamError, match="model.method.lamda_ent_main: not a setting of "
                       "model/method=minent; its settings: lambda_ent_aux, lambda_ent_main"):  # fmt: skip
        unused_method_settings(cfg.model.method)

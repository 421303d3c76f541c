"""What every adaptation method shares: the :class:`Method` interface, the two-domain forward /
backward (:class:`DomainPass`) and the segmenter's step on the source loss plus a method's
target term (:func:`segmenter_step`).

A method computes the losses of one training iteration and steps the optimisers of the
:class:`~uss_slam.train.module.AdversarialSegmentation` it is given (Lightning manual
optimisation). The module owns the segmenter, its optimiser, the poly schedules, the iteration
counter, logging and checkpoints; a method owns whatever else it trains (discriminators, a
teacher), declares their optimisers (:meth:`Method.optimizers`) and its weights. The segmenter
stays a plain network that never sees domains.
"""

from __future__ import annotations

import contextlib
import functools
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, Protocol, TypeVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from uss_slam.core.errors import UssSlamError
from uss_slam.models.deeplab import SegmenterOutput
from uss_slam.train.losses import LossWeights, segmentation_loss, upsample

TrainBatch = dict[str, dict[str, Any]]
"""``{"source": {"image" (N, 3, H, W), "label" (N, H, W) int64, ...}, "target": {"image", ...}}``."""
StepValues = dict[str, Tensor]
"""Detached values of one iteration, named like the logged keys without ``train/``."""
OptimizerFactory = Callable[..., torch.optim.Optimizer]
"""An optimiser class with its settings bound (a Hydra ``_partial_``), taking ``params``."""


class TrainingModule(Protocol):
    """What a method uses of the LightningModule that trains it
    (:class:`~uss_slam.train.module.AdversarialSegmentation`): its segmenter and optimisers,
    the source loss weights, the iteration counter and budget, the BatchNorm and batching options, and
    Lightning's ``manual_backward``."""

    segmenter: nn.Module
    loss_weights: LossWeights
    iteration: int
    max_iters: int
    batch_domains: bool
    domain_batch_norm: str
    channels_last: bool
    global_rank: int

    def segmenter_optimizer(self) -> Any: ...

    def method_optimizer(self, index: int) -> Any: ...

    def manual_backward(self, loss: Tensor, *args: Any, **kwargs: Any) -> None: ...


In = TypeVar("In")
Out = TypeVar("Out")


class NonFiniteLossError(UssSlamError):
    """A loss became NaN or infinite; raised before any optimiser step applies it."""


def check_weight(key: str, value: object) -> float:
    """``value`` as a float when it is a number ``>= 0``, else one line naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise UssSlamError(f"{key}: expected a number >= 0, got {value!r}")
    return float(value)


def check_finite(iteration: int, **losses: Tensor) -> None:
    """Raise :class:`NonFiniteLossError` naming the first non-finite loss (one host sync for
    all of them; names are looked up only on failure)."""
    if bool(torch.isfinite(torch.stack([v.detach() for v in losses.values()])).all()):
        return
    for name, value in losses.items():
        if not bool(torch.isfinite(value)):
            raise NonFiniteLossError(
                f"non-finite {name} ({value.item()}) at iteration {iteration}: training "
                "stopped before applying it; the last checkpoint written is the last good state"
            )


BATCH_NORM_LAYERS: tuple[type[nn.Module], ...] = (
    nn.BatchNorm1d,
    nn.BatchNorm2d,
    nn.BatchNorm3d,
    nn.SyncBatchNorm,
)
"""The BatchNorm layer types (torch's public classes)."""


def uses_batch_statistics(net: nn.Module) -> bool:
    """True when a layer of ``net`` normalises with batch statistics (BatchNorm in train mode):
    then source and target must not share a forward pass."""
    return any(m.training for m in net.modules() if isinstance(m, BATCH_NORM_LAYERS))


def can_batch_domains(module: TrainingModule, source: Tensor, target: Tensor) -> bool:
    """Source and target through one forward: when every layer treats samples independently
    (frozen BN), the module allows it (``batch_domains``) and the crops have one size (the same
    numbers, better CPU/GPU use); with BatchNorm in train mode only under
    ``domain_batch_norm="joint"`` (statistics of both batches: other numbers, by choice)."""
    same_size = source.shape[1:] == target.shape[1:]
    if uses_batch_statistics(module.segmenter):
        if module.domain_batch_norm != "joint":
            return False
        if not same_size:
            raise UssSlamError(
                "model.domain_batch_norm=joint normalises source and target in one batch: their "
                f"crops must have one size, got {tuple(source.shape[-2:])} and "
                f"{tuple(target.shape[-2:])} (set data.source/target.transform.crop_size alike)"
            )
        return True
    return module.batch_domains and same_size


def with_running_statistics(net: nn.Module, images: Tensor) -> Any:
    """``net(images)`` with every BatchNorm layer in train mode normalising by its running
    statistics instead, as at evaluation, and leaving them unchanged (gradients flow as through
    any affine layer); ``domain_batch_norm="running"``'s target forward."""
    layers = [m for m in net.modules() if isinstance(m, BATCH_NORM_LAYERS) and m.training]
    for m in layers:
        m.eval()
    try:
        return net(images)
    finally:
        for m in layers:
            m.train()


def _like(template: tuple, items: list[Any]) -> tuple:
    """A tuple of ``template``'s type (plain or named) holding ``items``."""
    return tuple(items) if type(template) is tuple else type(template)(*items)


def _cat(a: Any, b: Any) -> Any:
    if isinstance(a, Tensor):
        return torch.cat([a, b])
    return _like(a, [_cat(x, y) for x, y in zip(a, b, strict=True)])


def _split(x: Any, n: int) -> tuple[Any, Any]:
    if isinstance(x, Tensor):
        return x[:n], x[n:]
    parts = [_split(v, n) for v in x]
    return _like(x, [p[0] for p in parts]), _like(x, [p[1] for p in parts])


def _batch_size(x: Any) -> int:
    return x.shape[0] if isinstance(x, Tensor) else _batch_size(x[0])


class DomainPass(Generic[In, Out]):
    """Source and target inputs through one network, and the backward passes of their losses.

    Call :meth:`source`, :meth:`backward` of the source loss, then :meth:`target` and
    :meth:`backward` of the target loss, inside ``with``:

    - unbatched: each call runs at once (the source graph is freed by its backward before the
      target forward: lowest peak memory);
    - batched: :meth:`source` runs the network once on both inputs concatenated along the batch
      (tensors, or tuples of tensors such as ``(aux, main)``), the losses are summed and leaving
      the ``with`` block runs one backward. The gradients are the same.

    An exception inside the block (e.g. :class:`NonFiniteLossError`) skips the pending backward.
    Without a target input the pass is the source forward and its backward.

    Args:
        net: ``net(inputs) -> outputs`` (e.g. the segmenter, or both discriminators).
        source: source inputs (batch first).
        target: target inputs, or ``None``.
        backward: ``LightningModule.manual_backward``.
        batched: run both domains as one batch (callers decide with :func:`can_batch_domains`).
        target_net: the network of the unbatched target forward when it differs from ``net``
            (e.g. :func:`with_running_statistics`).
    """

    def __init__(
        self,
        net: Callable[[In], Out],
        source: In,
        target: In | None,
        backward: Callable[[Tensor], None],
        batched: bool,
        target_net: Callable[[In], Out] | None = None,
    ) -> None:
        self.net = net
        self.target_net = net if target_net is None else target_net
        self.inputs = (source, target)
        self.run_backward = backward
        self.batched = batched and target is not None
        self._target_output: Out | None = None
        self._pending: Tensor | None = None

    def __enter__(self) -> DomainPass[In, Out]:
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        if kind is None and self._pending is not None:
            self.run_backward(self._pending)
        self._pending = None

    def source(self) -> Out:
        source, target = self.inputs
        if not self.batched:
            return self.net(source)
        out_src, self._target_output = _split(self.net(_cat(source, target)), _batch_size(source))
        return out_src

    def target(self) -> Out:
        target = self.inputs[1]
        if target is None:
            raise ValueError("DomainPass.target(): the pass has no target input")
        if self.batched:
            if self._target_output is None:
                raise ValueError("DomainPass.target() before source() in a batched pass")
            return self._target_output
        return self.target_net(target)

    def backward(self, loss: Tensor) -> None:
        if not self.batched:
            self.run_backward(loss)
        else:
            self._pending = loss if self._pending is None else self._pending + loss


def weighted_heads(
    iteration: int,
    names: tuple[str, str, str],
    losses: tuple[Tensor, Tensor],
    weights: tuple[float, float],
) -> Tensor:
    """``weights[0]·losses[0] + weights[1]·losses[1]`` (aux, main), checked finite with the
    names ``(aux, main, total)`` in :class:`NonFiniteLossError`'s message."""
    total = weights[0] * losses[0] + weights[1] * losses[1]
    check_finite(iteration, **{names[0]: losses[0], names[1]: losses[1], names[2]: total})
    return total


class SourceSegmentation:
    """``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)`` of source logits (upsampled to the
    label size), with the log-probabilities kept for the discriminators.

    Attributes:
        loss: the weighted sum (to back-propagate).
        log_probs: ``(aux, main)`` log-softmax maps ``(N, C, H, W)`` at label size.
        values: detached ``loss_seg_src_aux`` / ``loss_seg_src_main``.
    """

    def __init__(
        self, pred: SegmenterOutput, labels: Tensor, weights: LossWeights, iteration: int
    ) -> None:
        size = labels.shape[-2:]
        logp_aux = F.log_softmax(upsample(pred.aux, size), dim=1)
        logp_main = F.log_softmax(upsample(pred.main, size), dim=1)
        loss_aux = segmentation_loss(logp_aux, labels)
        loss_main = segmentation_loss(logp_main, labels)
        self.loss = weighted_heads(
            iteration,
            ("loss_seg_src_aux", "loss_seg_src_main", "loss_seg"),
            (loss_aux, loss_main),
            (weights.lambda_seg_aux, weights.lambda_seg_main),
        )
        self.log_probs = (logp_aux, logp_main)
        self.values: StepValues = {
            "loss_seg_src_aux": loss_aux.detach(),
            "loss_seg_src_main": loss_main.detach(),
        }


@dataclass
class TargetLoss:
    """A method's per-head loss on the second input of the segmenter step (target or mixed
    crops): ``L = weights[0]·aux + weights[1]·main``.

    Attributes:
        prefix: logged name without the head, e.g. ``loss_adv_trg`` (values
            ``loss_adv_trg_aux`` / ``loss_adv_trg_main``).
        total: name of the weighted sum in error messages, e.g. ``loss_adv``.
        aux: the aux head's loss (0-d).
        main: the main head's loss (0-d).
        weights: ``(λ_aux, λ_main)``.
        keep: whatever the method needs after the segmenter step (AdaptSegNet: the target maps
            its discriminators then learn from).
    """

    prefix: str
    total: str
    aux: Tensor
    main: Tensor
    weights: tuple[float, float]
    keep: Any = None

    def weighted(self, iteration: int) -> Tensor:
        """The weighted sum, checked finite (:class:`NonFiniteLossError` names the term)."""
        return weighted_heads(
            iteration,
            (f"{self.prefix}_aux", f"{self.prefix}_main", self.total),
            (self.aux, self.main),
            self.weights,
        )

    @property
    def values(self) -> StepValues:
        """Detached ``<prefix>_aux`` / ``<prefix>_main``."""
        return {f"{self.prefix}_aux": self.aux.detach(), f"{self.prefix}_main": self.main.detach()}


@dataclass
class SegmenterStep:
    """What :func:`segmenter_step` computed.

    Attributes:
        source: the source segmentation loss and log-probabilities.
        target: the method's target loss, or ``None`` without a second input.
        batched: both inputs went through one forward (the discriminator step may batch too).
    """

    source: SourceSegmentation
    target: TargetLoss | None
    batched: bool

    @property
    def values(self) -> StepValues:
        """The detached losses of both terms, named like the logged keys."""
        return {**self.source.values, **(self.target.values if self.target else {})}


def segmenter_step(
    module: TrainingModule,
    source: dict[str, Tensor],
    target: Tensor | None = None,
    target_loss: Callable[[SegmenterOutput], TargetLoss] | None = None,
) -> SegmenterStep:
    """One optimiser step of the segmenter on ``L_seg`` of the source batch plus, when given,
    ``target_loss`` of its output on ``target`` images: the tail every method shares (zero the
    gradients, the two-domain pass of :class:`DomainPass`, loss weighting, finiteness checks,
    backward, the SGD step).

    Args:
        module: the LightningModule (segmenter, optimiser, loss weights, iteration).
        source: ``{"image" (N, 3, H, W), "label" (N, H, W) int64}``.
        target: ``(M, 3, H', W')`` images of the second term (target or mixed crops), or
            ``None`` (source only).
        target_loss: the method's loss of the segmenter's output on ``target`` (required with
            ``target``); called inside the pass, so its graph is back-propagated.
    """
    if (target is None) != (target_loss is None):
        raise ValueError("segmenter_step: give both target and target_loss, or neither")
    opt_seg = module.segmenter_optimizer()
    images = source["image"]
    batched = target is not None and can_batch_domains(module, images, target)
    opt_seg.zero_grad()
    term = None
    target_net = None
    if module.domain_batch_norm == "running" and uses_batch_statistics(module.segmenter):
        target_net = functools.partial(with_running_statistics, module.segmenter)
    with DomainPass(
        module.segmenter, images, target, module.manual_backward, batched, target_net
    ) as seg:
        src = SourceSegmentation(
            seg.source(), source["label"], module.loss_weights, module.iteration
        )
        seg.backward(src.loss)
        if target_loss is not None:
            term = target_loss(seg.target())
            seg.backward(term.weighted(module.iteration))
    opt_seg.step()
    return SegmenterStep(src, term, batched)


class Method(nn.Module, ABC):
    """One adaptation method: the losses and optimiser steps of a training iteration.

    Subclasses set the class attributes and implement :meth:`training_step`. What a method
    trains besides the segmenter (discriminators, a teacher) it registers as its own submodules
    or buffers, which then move with the LightningModule and are saved in its checkpoints (under
    ``method.``); their optimisers it declares in :meth:`optimizers`, and the module builds them
    (with their poly schedules) after the segmenter's.

    Attributes:
        name: the option of the config group ``model/method`` (stored in checkpoints).
        adapts: the method trains on target frames (callbacks that pick a domain, such as
            ``PreciseBatchNorm(domain="auto")``, then pick the target).
        trains_discriminators: the method trains two domain discriminators (the experiment grid
            trains it at every discriminator depth it sweeps).
        needs_equal_crops: the method combines source and target crops pixel by pixel:
            ``uss-train`` refuses unequal ``data.*.transform.crop_size`` before any work.
    """

    name: ClassVar[str]
    adapts: ClassVar[bool]
    trains_discriminators: ClassVar[bool] = False
    needs_equal_crops: ClassVar[bool] = False

    @abstractmethod
    def training_step(self, module: TrainingModule, batch: TrainBatch) -> StepValues:
        """Compute the losses of one iteration, back-propagate them and step the optimisers
        (:func:`segmenter_step` first, then the method's own through
        ``module.method_optimizer(i)``). The images are already on the module's device and
        memory format. Returns detached values for :meth:`train_scalars`."""

    def optimizers(self) -> list[tuple[OptimizerFactory, list[nn.Parameter]]]:
        """``(factory, params)`` of each optimiser of the method's own networks, in the order
        ``module.method_optimizer(i)`` returns them (none by default)."""
        return []

    def settings(self) -> dict[str, Any]:
        """The method's settings a checkpoint keeps (its weights, its optimisers' factories), so
        that a resume with other values is noticed (``model.method.<key>``)."""
        return {}

    @property
    def discriminators(self) -> tuple[nn.Module, ...] | None:
        """The domain discriminators the method trains, or ``None``."""
        return None

    def summary(self) -> dict[str, float]:
        """Figures of the method's own over the whole training (or since a resume), added to
        the metrics ``uss-train`` returns and logs at the end (none by default)."""
        return {}

    def train_scalars(self, step: StepValues) -> dict[str, Tensor]:
        """The logged ``train/*`` scalars of one iteration (only computed on logging steps);
        by default every value of :meth:`training_step` as ``train/<name>``."""
        return {f"train/{name}": value for name, value in step.items()}

    def extra_repr(self) -> str:
        return f"name={self.name!r}"


@contextlib.contextmanager
def frozen(*nets: nn.Module) -> Iterator[None]:
    """``requires_grad=False`` on the trainable parameters of ``nets`` inside the block, restored
    afterwards (also on errors); parameters frozen before stay frozen."""
    params = [p for net in nets for p in net.parameters() if p.requires_grad]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)

"""``AdversarialSegmentation``: the LightningModule that trains a segmenter with an adaptation
method.

The segmenter (a plain :class:`~uss_slam.models.DeepLabV2` or :class:`~uss_slam.models.PSPNet`)
never sees domains. This module owns it, its SGD optimiser with its poly schedule, the own
iteration counter, logging, validation and checkpoints (manual optimisation). What one training
iteration computes is the *method*'s (config group ``model/method``,
:mod:`uss_slam.train.methods`):

- ``adaptsegnet``: the paper's Algorithm 1, adversarial output-space adaptation (the default);
- ``advent``: the same with the discriminators on entropy maps (ADVENT);
- ``minent``: direct entropy minimisation on the target (ADVENT's MinEnt);
- ``self_training``: mean-teacher pseudo-labels with ClassMix (DACS / DAFormer);
- ``source_only``: the "without ATL" baseline.

The method owns what it trains besides the segmenter: the two PatchGAN discriminators of
``adaptsegnet`` / ``advent``, their optimiser and the adversarial weights are the method's
(``model.method.*``, saved under ``method.`` in checkpoints); this module builds the optimisers
the method declares, after the segmenter's, each with its poly schedule. Checkpoints written
when the module held the discriminators (``d_aux.*`` / ``d_main.*``) load all the same.

Speed options that leave the computation unchanged (tested against the eager step):
``compile`` (``torch.compile`` of the segmenter and both discriminators), ``channels_last``,
``batch_domains`` and ``optimizer_kernels`` (foreach / fused optimiser steps). Mixed precision
is the trainer's (``trainer.precision=bf16-mixed`` / ``16-mixed``); the losses are computed in
float32 under it (:mod:`uss_slam.train.losses`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import asdict
from typing import Annotated, Any, Literal

import torch
from lightning.pytorch import LightningModule
from torch import Tensor
from torch.optim import Optimizer
from torchmetrics.classification import MulticlassConfusionMatrix

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import UssSlamError
from uss_slam.core.ranges import Range
from uss_slam.core.seg_metrics import iou_per_class
from uss_slam.models.deeplab import DeepLabV2, SegmenterOutput
from uss_slam.train.losses import LossWeights, upsample
from uss_slam.train.methods import Method, StepValues, TrainBatch
from uss_slam.train.methods.base import NonFiniteLossError, OptimizerFactory
from uss_slam.train.schedules import PolyLR, poly_horizon

log = logging.getLogger(__name__)

RESUME_IGNORED = ("backbone", "adaptation")
"""``hyper_parameters`` not compared on resume: the architecture is checked weight by weight,
``adaptation`` follows from ``method``."""
RESUME_KEYS = {"method": "model/method"}
"""``hyper_parameters`` key -> the config key a user changes (others: ``model.<key>``; the
method's own settings, ``method_settings.<key>``: ``model.method.<key>``)."""


def factory_settings(factory: Any) -> dict[str, Any] | None:
    """An optimiser factory (a ``functools.partial`` of ``_partial_: true``) as plain values:
    ``{"name": "SGD", "lr": ..., ...}`` (what a checkpoint keeps, so that a resume with another
    learning rate is noticed); None when it is not a partial."""
    keywords = getattr(factory, "keywords", None)
    if factory is None or not isinstance(keywords, dict):
        return None
    settings: dict[str, Any] = {"name": getattr(factory.func, "__name__", str(factory.func))}
    for key, value in keywords.items():
        if isinstance(value, (bool, int, float, str)) or value is None:
            settings[key] = value
        elif isinstance(value, Sequence) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        ):
            settings[key] = list(value)
    return settings


def resume_differences(saved: dict[str, Any], current: dict[str, Any]) -> list[str]:
    """``key (checkpoint -> now)`` for every setting of the model that a resumed run would
    silently not apply or apply half-way (another learning rate, method, ``max_iters``, loss
    weight): ``hyper_parameters`` of the checkpoint against those of the configured model.
    Keys an older checkpoint lacks are not compared."""

    def flat(values: dict[str, Any], prefix: str = "") -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, value in values.items():
            name = f"{prefix}{key}"
            if isinstance(value, dict):
                out.update(flat(value, f"{name}."))
            else:
                out[name] = list(value) if isinstance(value, tuple) else value
        return out

    theirs, mine = flat(dict(saved)), flat(dict(current))
    differences = []
    for key, value in mine.items():
        top = key.split(".")[0]
        if top in RESUME_IGNORED or key not in theirs or theirs[key] == value:
            continue
        if isinstance(value, (list, tuple)) and list(value) == list(theirs[key] or []):
            continue
        shown = RESUME_KEYS.get(key, f"model.{key}").replace(
            "model.method_settings.", "model.method."
        )
        differences.append(f"{shown} ({theirs[key]!r} -> {value!r})")
    return differences


OptimizerKernels = Literal["default", "foreach", "fused"]
DomainBatchNorm = Literal["separate", "joint", "running"]

COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
"""``torch.compile`` modes of the inductor backend."""

LEGACY_METHOD_PREFIXES = ("d_aux.", "d_main.")
"""State-dict key prefixes of the discriminators in checkpoints written when the module held
them (now ``method.d_aux.`` / ``method.d_main.``)."""

__all__ = ["AdversarialSegmentation", "NonFiniteLossError"]


class AdversarialSegmentation(LightningModule):
    """A two-head segmenter trained by an adaptation method, with manual optimisation.

    Args:
        net: the segmenter; ``net(images)`` returns ``(aux, main)`` logits and
            ``net.param_groups(lr, head_lr_mult)`` its optimiser groups.
        optimizer: segmenter optimiser factory taking ``params`` (SGD, with ``lr``).
        method: what one iteration computes and what else it trains
            (:class:`~uss_slam.train.methods.Method`, config group ``model/method``).
        loss: the weights of the source segmentation loss (both heads).
        max_iters: training iterations (own counter: ``global_step`` counts optimiser steps);
            training stops there.
        poly_power: exponent of the poly schedules.
        poly_total_iters: horizon of the poly schedules (where the rate would reach 0); ``None``
            = ``max_iters × 250/150``, the reference code's 250k schedule stopped at 150k (the
            rate ends at 0.44× its base); ``max_iters`` decays to 0 at the last iteration.
        head_lr_mult: learning-rate multiplier of the segmenter heads.
        class_names: names for ``val/IoU/<class>``; their count is the number of classes.
        batch_domains: run source and target through one segmenter forward and one
            discriminator pass per head when no layer uses batch statistics (frozen BN) and the
            crops have one size. Identical losses and gradients; peak activation memory holds
            both domains at once (set ``False`` on a tight GPU).
        domain_batch_norm: what BatchNorm layers in train mode (a segmenter trained from
            scratch) normalise the target batch with: ``separate`` (each domain's batch its own
            statistics: two forwards; the target maps are then normalised like AdaBN's and a
            discriminator finds little domain in them, ``studies/d_probe.py``), ``joint``
            (source and target batch in one forward, statistics of both; needs crops of one
            size) or ``running`` (the target batch by the running statistics of the source
            batches, as at evaluation with source statistics; two forwards). Ignored when no
            layer uses batch statistics.
        channels_last: NHWC memory layout for the networks and inputs (same results).
        compile: ``torch.compile`` the segmenter and the discriminators in place (parameter
            names, checkpoints and exports stay those of the eager networks). Compilation runs
            in the first iteration (and again at the first validation batch, eval mode); its
            cost is logged once as ``train/compile_s``.
        compile_mode: ``torch.compile`` mode (inductor: ``default``, ``reduce-overhead``,
            ``max-autotune``, ``max-autotune-no-cudagraphs``).
        compile_backend: ``torch.compile`` backend (``inductor``: C++ on CPU, Triton on GPU).
        compile_dynamic: ``torch.compile``'s ``dynamic``: ``False`` compiles one graph per input
            shape (the discriminators see two batch sizes when domains are batched), ``None``
            lets torch decide after a shape changes.
        optimizer_kernels: how the optimisers update the weights: ``default`` (the optimiser
            config's own choice; torch picks foreach on GPUs, a loop over tensors on CPU),
            ``foreach`` (multi-tensor kernels) or ``fused`` (one fused kernel where the optimiser
            and the device support it, else foreach; logged). Same update up to rounding.
    """

    def __init__(
        self,
        net: DeepLabV2,
        optimizer: OptimizerFactory,
        method: Method,
        loss: LossWeights | None = None,
        max_iters: Annotated[int, Range(min=1)] = 250_000,
        poly_power: Annotated[float, Range(gt=0)] = 0.9,
        poly_total_iters: Annotated[int | None, Range(min=1)] = None,
        head_lr_mult: Annotated[float, Range(gt=0)] = 10.0,
        class_names: Sequence[str] = CLASS_NAMES,
        batch_domains: bool = True,
        domain_batch_norm: DomainBatchNorm = "separate",
        channels_last: bool = False,
        compile: bool = False,
        compile_mode: str = "default",
        compile_backend: str = "inductor",
        compile_dynamic: bool | None = False,
        optimizer_kernels: OptimizerKernels = "default",
    ) -> None:
        super().__init__()  # the values' types and ranges: the config's schema (uss-train)
        self._check_net(net, class_names, domain_batch_norm)
        self.automatic_optimization = False
        self.segmenter = net
        self.method = self._check_method(method)
        self.optimizer_factory = optimizer
        self.loss_weights = loss if loss is not None else LossWeights()
        self.max_iters = max_iters
        self.poly_power = poly_power
        self.poly_total_iters = poly_horizon(max_iters, poly_total_iters)
        self.head_lr_mult = head_lr_mult
        self.class_names = tuple(class_names)
        self.batch_domains = batch_domains
        self.domain_batch_norm = domain_batch_norm
        self.channels_last = channels_last
        self.compile_networks = compile
        self.compile_options = self._check_compile_options(
            compile_mode, compile_backend, compile_dynamic
        )
        self.optimizer_kernels = optimizer_kernels
        self._compiled = False
        # Host seconds of the first two iterations this process runs with compiled networks:
        # their difference is the compilation cost (train/compile_s).
        self._first_iterations: list[float] = []
        self._batch_started = 0.0
        self.compile_seconds: float | None = None
        """Compilation cost logged as ``train/compile_s`` (set after the second iteration)."""
        self.iteration = 0
        """Completed training iterations (saved in checkpoints)."""
        self._step_values: tuple[StepValues, int] | None = None
        # Pixel counts (truth x prediction) summed over the validation set and, under DDP,
        # over the ranks (a torchmetrics state); the IoUs come from uss_slam.core.seg_metrics.
        self.val_confusion = MulticlassConfusionMatrix(
            num_classes=len(self.class_names), ignore_index=IGNORE_INDEX
        )
        self._save_settings()

    def _save_settings(self) -> None:
        """The run's settings as the checkpoint's hyperparameters: plain values only, so that
        checkpoints load with ``torch.load(weights_only=True)``."""
        self.save_hyperparameters(
            {
                "loss": asdict(self.loss_weights),
                "max_iters": self.max_iters,
                "poly_power": self.poly_power,
                "poly_total_iters": self.poly_total_iters,
                "head_lr_mult": self.head_lr_mult,
                "method": self.method.name,
                "adaptation": self.method.adapts,
                "class_names": list(self.class_names),
                "backbone": getattr(self.segmenter, "backbone_name", type(self.segmenter).__name__),
                "optimizer": factory_settings(self.optimizer_factory),
                "method_settings": {
                    key: factory_settings(value) if callable(value) else value
                    for key, value in self.method.settings().items()
                },
            },
            logger=False,
        )

    @staticmethod
    def _check_net(net: DeepLabV2, class_names: Sequence[str], domain_batch_norm: str) -> None:
        """The network agrees with the class list and with ``domain_batch_norm``."""
        num_classes = getattr(net, "num_classes", None)
        if num_classes is not None and num_classes != len(class_names):
            raise UssSlamError(
                f"model.net.num_classes is {num_classes} but model.class_names lists "
                f"{len(class_names)} ({', '.join(class_names)}); they must agree"
            )
        if getattr(net, "batchnorm", None) == "reference" and domain_batch_norm != "separate":
            raise UssSlamError(
                f"model.domain_batch_norm={domain_batch_norm} contradicts "
                "model.net.batchnorm=reference (source and target forwards apart, each "
                "normalised by its own batch): set model.domain_batch_norm=separate"
            )

    @staticmethod
    def _check_method(method: Method) -> Method:
        if not isinstance(method, Method):
            raise UssSlamError(
                f"model.method must be an adaptation method (uss_slam.train.methods.Method), "
                f"got {type(method).__name__}"
            )
        return method

    @staticmethod
    def _check_compile_options(mode: str, backend: str, dynamic: bool | None) -> dict[str, Any]:
        backends = torch.compiler.list_backends(exclude_tags=())
        if backend not in backends:
            raise UssSlamError(
                f"model.compile_backend must be one of {', '.join(sorted(backends))}, "
                f"got {backend!r}"
            )
        if backend == "inductor" and mode not in COMPILE_MODES:
            raise UssSlamError(
                f"model.compile_mode must be one of {', '.join(COMPILE_MODES)}, got {mode!r}"
            )
        options: dict[str, Any] = {"backend": backend, "dynamic": dynamic}
        if backend == "inductor":
            options["mode"] = mode
        return options

    @property
    def adaptation(self) -> bool:
        """True when the method trains on target frames (read-only; choose the method with
        ``model/method``)."""
        return self.method.adapts

    # ------------------------------------------------------------------ optimisers

    def configure_optimizers(self) -> tuple[list[Optimizer], list[PolyLR]]:
        """The segmenter's optimiser, then those the method declares for its own networks
        (:meth:`~uss_slam.train.methods.Method.optimizers`); one poly schedule each."""
        lr = getattr(self.optimizer_factory, "keywords", {}).get("lr")
        if lr is None:
            raise UssSlamError("model.optimizer must set lr (the backbone learning rate)")
        optimizers = [
            self._optimizer(
                self.optimizer_factory, self.segmenter.param_groups(lr, self.head_lr_mult)
            )
        ]
        optimizers += [
            self._optimizer(factory, params) for factory, params in self.method.optimizers()
        ]
        schedules = [PolyLR(opt, self.poly_total_iters, self.poly_power) for opt in optimizers]
        return optimizers, schedules

    def _optimizers(self) -> list[Any]:
        found = self.optimizers()
        return found if isinstance(found, list) else [found]

    def segmenter_optimizer(self) -> Any:
        """The segmenter's (Lightning-wrapped) optimiser."""
        return self._optimizers()[0]

    def method_optimizer(self, index: int) -> Any:
        """The (Lightning-wrapped) optimiser ``index`` of those the method declares."""
        optimizers = self._optimizers()[1:]
        if not 0 <= index < len(optimizers):
            raise UssSlamError(
                f"model/method={self.method.name} declares {len(optimizers)} optimiser(s) of its "
                f"own, asked for number {index}"
            )
        return optimizers[index]

    def _optimizer(self, factory: OptimizerFactory, params: list[Any]) -> Optimizer:
        """``factory(params)`` with the kernels of ``optimizer_kernels``."""
        if self.optimizer_kernels == "default":
            return factory(params=params)
        if self.optimizer_kernels == "fused":
            try:
                return factory(params=params, fused=True, foreach=False)
            except (RuntimeError, TypeError) as error:  # no fused kernel for this class / device
                log.info("fused optimiser step unavailable (%s): using foreach", error)
        return factory(params=params, foreach=True)

    # ------------------------------------------------------------------ training

    def forward(self, images: Tensor) -> SegmenterOutput:
        return self.segmenter(images)

    def setup(self, stage: str) -> None:
        nets = (self.segmenter, *(self.method.discriminators or ()))
        if self.channels_last:
            for net in nets:
                net.to(memory_format=torch.channels_last)
        if self.compile_networks and not self._compiled:
            # In place (nn.Module.compile): the state dict keeps the eager names. Compilation
            # itself happens at the first call of each network (first iteration).
            for net in nets:
                net.compile(**self.compile_options)
            self._compiled = True

    def _prepare(self, images: Tensor) -> Tensor:
        return (
            images.contiguous(memory_format=torch.channels_last) if self.channels_last else images
        )

    def training_step(self, batch: TrainBatch, batch_idx: int) -> None:
        prepared = {
            domain: {**sample, "image": self._prepare(sample["image"])}
            for domain, sample in batch.items()
        }
        # Detached values for the train/* scalars; turned into the logged numbers only on
        # logging steps (see on_train_batch_end).
        step = self.method.training_step(self, prepared)
        schedules = self.lr_schedulers()
        sched_seg, *sched_method = schedules if isinstance(schedules, list) else [schedules]
        for schedule in sched_method:
            schedule.step()
        sched_seg.step()
        self.iteration += 1
        self._step_values = (step, batch["source"]["image"].shape[0])
        # Every step: the progress bar and the checkpoint file names read it.
        self.log("iteration", float(self.iteration), on_step=True, prog_bar=True, logger=False)

    @torch.no_grad()
    def _train_scalars(self, step: StepValues) -> dict[str, Tensor]:
        """The logged ``train/*`` scalars from one step's detached values (the method's)."""
        return self.method.train_scalars(step)

    def _logs_this_step(self) -> bool:
        """True when Lightning hands this step's metrics to the loggers (its own rule): every
        step of a ``fast_dev_run``; else every ``trainer.log_every_n_steps``-th training batch
        (counted from 0 over the whole run, resumes included) and the step that stops
        training."""
        trainer = self.trainer
        if trainer.fast_dev_run:
            return True
        if trainer.log_every_n_steps == 0:
            return False
        batches_before = trainer.fit_loop.epoch_loop.total_batch_idx
        return (batches_before + 1) % trainer.log_every_n_steps == 0 or trainer.should_stop

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> int | None:
        self._step_values = None
        if self._compiled and len(self._first_iterations) < 2:
            self._batch_started = time.perf_counter()
        if self.iteration >= self.max_iters:
            self.trainer.should_stop = True
            return -1  # resumed a finished run: skip the rest of the epoch
        return None

    def on_train_batch_end(self, outputs: Any, batch: Any, batch_idx: int) -> None:
        if self.iteration >= self.max_iters:
            self.trainer.should_stop = True
        if self._compiled and len(self._first_iterations) < 2 and self._step_values is not None:
            self._record_compile_time(time.perf_counter() - self._batch_started)
        # Logged here, after should_stop is known, and only on the steps that reach the loggers
        # (the values in between would never be written): each self.log costs ~0.5 ms of
        # Lightning bookkeeping, 8 scalars at every step were ~2% of a demo iteration.
        if self._step_values is not None and self._logs_this_step():
            step, n_src = self._step_values
            self.log_dict(self._train_scalars(step), on_step=True, on_epoch=False, batch_size=n_src)
        self._step_values = None

    def _record_compile_time(self, seconds: float) -> None:
        """After the second compiled iteration: log the first one's extra host time over the
        second (compilation, plus one-off warm-up that an eager first iteration has too) once,
        as a log line and ``train/compile_s``."""
        self._first_iterations.append(seconds)
        if len(self._first_iterations) < 2:
            return
        first, second = self._first_iterations
        compile_s = max(first - second, 0.0)
        self.compile_seconds = compile_s
        if self.trainer.is_global_zero:
            log.info(
                "torch.compile: first iteration %.1f s, second %.2f s: compilation ~%.1f s",
                first,
                second,
                compile_s,
            )
        for logger in self.loggers:
            logger.log_metrics({"train/compile_s": compile_s}, step=self.iteration - 1)

    # ------------------------------------------------------------------ validation

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        labels = batch["label"]
        logits = upsample(self.segmenter(self._prepare(batch["image"])).main, labels.shape[-2:])
        self.val_confusion.update(logits.argmax(dim=1), labels)

    def on_validation_epoch_end(self) -> None:
        matrix = self.val_confusion.compute()
        self.val_confusion.reset()
        # NaN for a class absent from truth and prediction; nanmean leaves it out of val/mIoU.
        iou = torch.from_numpy(iou_per_class(matrix.cpu().numpy()))
        iou = iou.to(device=matrix.device, dtype=torch.float32)
        self.log_dict({f"val/IoU/{name}": iou[i] for i, name in enumerate(self.class_names)})
        self.log("val/mIoU", torch.nanmean(iou), prog_bar=True)

    # ------------------------------------------------------------------ checkpoints

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["iteration"] = self.iteration

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        if "iteration" not in checkpoint:
            raise UssSlamError("checkpoint has no 'iteration': not written by uss-train")
        self.iteration = int(checkpoint["iteration"])
        if "state_dict" in checkpoint:
            checkpoint["state_dict"] = self.loadable_state(
                checkpoint["state_dict"], checkpoint.get("hyper_parameters", {}).get("method")
            )
        # Checkpoints written when every method built discriminators saved their optimiser and
        # schedule after the segmenter's; a method with fewer optimisers of its own keeps those
        # it declares.
        kept = 1 + len(self.method.optimizers())
        for entry in ("optimizer_states", "lr_schedulers"):
            if entry in checkpoint:
                checkpoint[entry] = checkpoint[entry][:kept]

    def loadable_state(self, state: dict[str, Any], method: str | None = None) -> dict[str, Any]:
        """A checkpoint's ``state_dict`` as this module loads it. Discriminators saved by the
        module of earlier versions (``d_aux.*`` / ``d_main.*``) become the method's
        (``method.d_aux.*``), or are dropped when the method trains none.

        Raises:
            UssSlamError: the method trains discriminators and the checkpoint (of ``method``,
                from its hyper-parameters) has none.
        """
        renamed = {
            (f"method.{k}" if k.startswith(LEGACY_METHOD_PREFIXES) else k): v
            for k, v in state.items()
        }
        wanted = tuple(f"method.{p}" for p in LEGACY_METHOD_PREFIXES)
        if self.method.discriminators is None:
            return {k: v for k, v in renamed.items() if not k.startswith(wanted)}
        if renamed and not any(k.startswith(wanted) for k in renamed):
            raise UssSlamError(
                f"checkpoint of model/method={method or 'unknown'} has no discriminators, which "
                f"model/method={self.method.name} trains: start a new run from its segmenter "
                "with model.net.weights_path=<checkpoint> instead of resuming it"
            )
        return renamed

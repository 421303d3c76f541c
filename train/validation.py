"""Label-free validators while training: :class:`TargetValidators`, a Lightning callback, and the
one validator that needs the torch model, :class:`BatchNormDistance`.

At validations (after :class:`~uss_slam.train.precise_bn.PreciseBatchNorm`, so on the state a
checkpoint of that validation holds), at most once per ``every_n_iterations`` iterations, the
callback runs the segmenter (eval mode, ``main`` head) on ``frames`` unlabelled target frames held
out of training (the data config's validation frames, labels unread) and on ``source_frames``
source images, computes the chosen validators of :mod:`uss_slam.core.validators` from their
softmax maps, and logs them as ``train/validator_<name>`` (TensorBoard, beside the
discriminators' ``train/d_acc_*``). With ``select: <name>`` it also keeps the checkpoint that
validator prefers as ``checkpoints/validator_<name>.ckpt`` (``last.ckpt`` stays what
``uss-export`` and the demo use unless told otherwise). Which validators: the ``validators``
config group (``configs/validators/``); what each is worth: ``docs/results/validators.md``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence, Sized
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from lightning.pytorch import Callback, LightningModule, Trainer
from torch import nn
from torch.utils.data import Dataset

from uss_slam.core.errors import UssSlamError
from uss_slam.core.validators import NEEDS_SOURCE, VALIDATORS, build_validators, downsample_maps
from uss_slam.train.methods.base import BATCH_NORM_LAYERS
from uss_slam.train.precise_bn import evenly_spaced

log = logging.getLogger(__name__)

TORCH_VALIDATORS = {"bn_distance"}
"""Validators computed from the torch model, not from softmax maps (train side only)."""


class BatchNormDistance:
    """Distance between the statistics of every BatchNorm layer's input on source and on target
    images: per channel the 2-Wasserstein distance of two Gaussians,
    ``sqrt((mu_s - mu_t)^2 + (sigma_s - sigma_t)^2)``, averaged over the channels, then over the
    layers. Lower is better (the features look alike).

    Reference: AdaBN (Li et al., "Revisiting Batch Normalization for Practical Domain
    Adaptation", 2016) takes BatchNorm statistics as the domain's signature; the Gaussian
    2-Wasserstein distance is Dowson & Landau (1982). Statistics are pooled over every pixel of
    every image fed with :meth:`update` (``domain`` ``source`` or ``target``)."""

    name = "bn_distance"
    higher_is_better = False

    def __init__(self, net: nn.Module) -> None:
        self.layers = [m for m in net.modules() if isinstance(m, BATCH_NORM_LAYERS)]
        self.sums: dict[str, list[list[torch.Tensor]]] = {}
        self._domain: str | None = None
        self._hooks: list[Any] = []

    def _hook(self, index: int):
        def record(module: nn.Module, inputs: tuple[torch.Tensor, ...], output: Any) -> None:
            if self._domain is None:
                return
            x = inputs[0].detach().double()
            dims = [d for d in range(x.ndim) if d != 1]
            stats = self.sums.setdefault(self._domain, [[] for _ in self.layers])[index]
            count = torch.tensor(float(x.numel() // x.shape[1]), dtype=torch.float64)
            row = torch.stack([x.sum(dims), (x * x).sum(dims)]).cpu(), count
            if stats:
                stats[0] = (stats[0][0] + row[0], stats[0][1] + row[1])
            else:
                stats.append(row)

        return record

    def __enter__(self) -> BatchNormDistance:
        self._hooks = [m.register_forward_hook(self._hook(i)) for i, m in enumerate(self.layers)]
        return self

    def __exit__(self, *exc: object) -> None:
        for h in self._hooks:
            h.remove()
        self._hooks = []

    def domain(self, name: str | None) -> None:
        """Which domain the next forwards are: ``source``, ``target`` or None (not recorded)."""
        self._domain = name

    def score(self) -> float:
        if not self.layers or set(self.sums) != {"source", "target"}:
            return float("nan")
        distances = []
        for s, t in zip(self.sums["source"], self.sums["target"], strict=True):
            (ss, sn), (ts, tn) = s[0], t[0]
            mu_s, mu_t = ss[0] / sn, ts[0] / tn
            sd_s = (ss[1] / sn - mu_s**2).clamp_min(0).sqrt()
            sd_t = (ts[1] / tn - mu_t**2).clamp_min(0).sqrt()
            distances.append(float(((mu_s - mu_t) ** 2 + (sd_s - sd_t) ** 2).sqrt().mean()))
        return float(np.mean(distances))


@torch.no_grad()
def softmax_batches(
    net: nn.Module, dataset: Dataset, indices: Sequence[int], batch_size: int, max_side: int
) -> Any:
    """Yield ``(N, C, h, w)`` float32 numpy softmax maps of ``net``'s ``main`` head (upsampled to
    the image, then :func:`~uss_slam.core.validators.downsample_maps` to ``max_side``) for
    ``dataset[i]["image"]`` (normalised ``(3, H, W)`` tensors), in batches of equal-size images."""
    device = next(net.parameters()).device
    batch: list[torch.Tensor] = []
    for k, i in enumerate(indices):
        batch.append(dataset[i]["image"])
        last = k == len(indices) - 1
        if (
            last
            or len(batch) == batch_size
            or batch[0].shape != dataset[indices[k + 1]]["image"].shape
        ):
            x = torch.stack(batch).to(device)
            out = F.interpolate(net(x).main, size=x.shape[-2:], mode="bilinear", align_corners=True)
            yield downsample_maps(F.softmax(out.float(), dim=1).cpu().numpy(), max_side)
            batch = []


def lazy_source(dataset: Any, transform: Any) -> Dataset:
    """The source dataset of :class:`TargetValidators` built when first used, not when the
    callback is (a config node with ``_partial_: true`` and ``_recursive_: false``): the
    callback can be composed and instantiated without the data on disk."""
    from hydra.utils import instantiate

    from uss_slam.datasets.datamodule import with_transform

    return with_transform(instantiate(dataset), instantiate(transform))


class TargetValidators(Callback):
    """Compute label-free validators at validations and log them (see the module docstring).

    Args:
        names: validators of :data:`~uss_slam.core.validators.VALIDATORS` (and ``bn_distance``).
        params: keyword arguments per validator (``{snd: {pixels_per_image: 64}}``).
        bn_distance: also compute :class:`BatchNormDistance` (needs ``source``).
        frames: target frames (evenly spaced over the validation set; its labels are not read).
        source_frames: source images for ``probe`` and ``bn_distance`` (evaluation transform).
        every_n_iterations: at most one computation per this many iterations (at validations).
        select: a validator whose preferred checkpoint is kept as ``validator_<name>.ckpt``.
        source: the source dataset (samples with a normalised ``image``); None: none (``probe``
            and ``bn_distance`` are then skipped, with one warning).
        max_side: the softmax maps' longest side for the validators (pixels).
    """

    def __init__(
        self,
        names: Sequence[str] = ("entropy", "im", "snd", "dynamic_share"),
        params: Mapping[str, Mapping[str, Any]] | None = None,
        bn_distance: bool = False,
        frames: int = 32,
        source_frames: int = 32,
        every_n_iterations: int = 100,
        select: str | None = None,
        source: Dataset | None = None,
        batch_size: int = 4,
        max_side: int = 160,
    ) -> None:
        names = list(names) + (
            ["bn_distance"] if bn_distance and "bn_distance" not in names else []
        )
        for key, value in (("frames", frames), ("every_n_iterations", every_n_iterations),
                           ("batch_size", batch_size), ("max_side", max_side)):  # fmt: skip
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise UssSlamError(
                    f"callbacks.target_validators.{key}: expected an integer >= 1, got {value!r}"
                )
        self.map_names = [n for n in names if n not in TORCH_VALIDATORS]
        build_validators(self.map_names, params, "callbacks.target_validators.names")  # checked now
        if select is not None and select not in names:
            raise UssSlamError(
                f"callbacks.target_validators.select: {select!r} is not one of the computed "
                f"validators ({', '.join(names)})"
            )
        self.names, self.params = names, dict(params or {})
        self.frames, self.source_frames = frames, source_frames
        self.every, self.select, self.source = every_n_iterations, select, source
        self.batch_size, self.max_side = batch_size, max_side
        self.last_iteration: int | None = None
        self.best: float | None = None
        self.latest: dict[str, float] = {}

    def _due(self, pl_module: LightningModule) -> bool:
        it = int(getattr(pl_module, "iteration", 0))
        if it == 0 or (self.last_iteration is not None and it - self.last_iteration < self.every):
            return False
        self.last_iteration = it
        return True

    def on_validation_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if trainer.sanity_checking or not self._due(pl_module):
            return
        target = getattr(trainer.datamodule, "val", None) if trainer.datamodule else None
        if not isinstance(target, Sized) or len(target) == 0:
            raise UssSlamError(
                "callbacks.target_validators: the data config has no validation frames (data.val)"
            )
        self.latest = self.compute(pl_module.segmenter, target)
        pl_module.log_dict(
            {f"train/validator_{k}": v for k, v in self.latest.items() if math.isfinite(v)}
        )

    def compute(self, net: nn.Module, target: Dataset) -> dict[str, float]:
        """``{name: score}`` of ``net`` (restored to its train/eval mode afterwards)."""
        validators = build_validators(
            self.map_names, self.params, "callbacks.target_validators.names"
        )
        wants_source = any(n in NEEDS_SOURCE or n in TORCH_VALIDATORS for n in self.names)
        if wants_source and callable(self.source) and not isinstance(self.source, Dataset):
            self.source = self.source()  # built at the first use (lazy_source)
        if wants_source and self.source is None:
            log.warning(
                "target validators: no source dataset; %s skipped",
                ", ".join(n for n in self.names if n in NEEDS_SOURCE | TORCH_VALIDATORS),
            )
        was_training = net.training
        net.eval()
        try:
            with BatchNormDistance(net) as bn:
                bn.domain("target")
                trg = evenly_spaced(self.frames, len(target))
                for prob in softmax_batches(net, target, trg, self.batch_size, self.max_side):
                    for v in validators.values():
                        v.update(prob)
                if wants_source and self.source is not None:
                    bn.domain("source")
                    src = evenly_spaced(self.source_frames, len(self.source))
                    for prob in softmax_batches(
                        net, self.source, src, self.batch_size, self.max_side
                    ):
                        for name in NEEDS_SOURCE & set(validators):
                            validators[name].update_source(prob)  # type: ignore[attr-defined]
                bn.domain(None)
        finally:
            net.train(was_training)
        scores = {name: v.score() for name, v in validators.items()}
        if "bn_distance" in self.names:
            scores["bn_distance"] = bn.score()
        return {n: scores[n] for n in self.names if n in scores}

    def _better(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        cls = VALIDATORS.get(self.select or "")
        lower = self.select == "bn_distance" or (cls is not None and cls.higher_is_better is False)
        if self.best is None:
            return True
        return value < self.best if lower else value > self.best

    def on_validation_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        if self.select is None or trainer.sanity_checking or self.select not in self.latest:
            return
        value = self.latest.pop(self.select)
        if not self._better(value):
            return
        self.best = value
        dirpath = Path(trainer.default_root_dir) / "checkpoints"
        for cb in trainer.checkpoint_callbacks:
            if getattr(cb, "dirpath", None):
                dirpath = Path(cb.dirpath)
                break
        trainer.save_checkpoint(dirpath / f"validator_{self.select}.ckpt")
        log.info(
            "validator %s = %.4g: kept %s",
            self.select,
            value,
            dirpath / f"validator_{self.select}.ckpt",
        )

    def state_dict(self) -> dict[str, Any]:
        return {"best": self.best, "last_iteration": self.last_iteration}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.best = state_dict.get("best")
        self.last_iteration = state_dict.get("last_iteration")

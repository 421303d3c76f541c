"""The memory a training needs, estimated from its settings before the first iteration
(``uss-train`` refuses a run that cannot fit: :func:`check_training_memory`).

The estimate counts, beyond what the process holds when it is made (the imports, the data
module, the networks' weights: its ``VmRSS``, which the memory available already excludes):

- the parameters of the segmenter and the discriminators, each 3 times in float32 (weights,
  their gradients, one optimiser state: SGD's momentum; Adam's two states count for the
  discriminators, which are small);
- the activations of one training forward, :data:`ACTIVATION_COPIES` times: the output of
  every leaf module of the segmenter for a batch of ``data.batch_size`` crops, and of each
  discriminator on that batch's class maps at crop size, kept for the backward pass, and their
  gradients during it. The networks run on torch's ``meta`` device for this: shapes only, no
  memory, no arithmetic (a fraction of a second);
- :data:`RUNTIME_BYTES`: what the trainer, the callbacks (validators, precise BatchNorm), the
  validation passes, checkpoint writing and the math libraries' caches add once training runs;
- :data:`WORKER_BYTES` per ``data.num_workers`` process.

Checked against the measured peaks of the settings users run (``studies/memory_peaks.py``,
docs/results/reliability.md): it is above each of them, so a run it lets pass fits as those
did; one it refuses may still fit with swap or less slack (``USS_SLAM_NO_MEMORY_CHECK=1``
tries). CPU training only: a GPU's memory is its own and is not compared.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import torch
from torch import nn
from torch.func import functional_call

from uss_slam.core.resources import check_memory, estimate_line

log = logging.getLogger(__name__)

FLOAT_BYTES = 4
PARAMETER_COPIES = 3
"""Weights, gradients and one optimiser state per parameter."""
ACTIVATION_COPIES = 2
"""Each kept output and, during the backward pass, its gradient."""
RUNTIME_BYTES = 320 * 2**20
"""Added after the estimate is made by everything but the batch's tensors: 183-217 MB in the
measured runs (Lightning, the validators, the first validation, the libraries' caches)."""
WORKER_BYTES = 200 * 2**20
"""One data-loading worker process's own pages (its decoding, its prefetched batches)."""


def _meta_leaf_elements(net: nn.Module, shape: Sequence[int]) -> int:
    """Elements of every leaf module's outputs in one forward of ``net`` on a ``shape`` input,
    run on the ``meta`` device (no memory used)."""
    total = 0

    def count(module: nn.Module, args: Any, output: Any) -> None:
        nonlocal total
        for tensor in output if isinstance(output, (tuple, list)) else (output,):
            if isinstance(tensor, torch.Tensor):
                total += tensor.numel()

    hooks = [m.register_forward_hook(count) for m in net.modules() if not list(m.children())]
    try:
        state = {name: torch.empty_like(t, device="meta")
                 for name, t in [*net.named_parameters(), *net.named_buffers()]}  # fmt: skip
        with torch.no_grad():
            functional_call(net, state, (torch.empty(*shape, device="meta"),))
    finally:
        for hook in hooks:
            hook.remove()
    return total


def training_bytes(model: nn.Module, batch: int, crop: tuple[int, int], workers: int = 0) -> int:
    """Estimated bytes to train ``model`` (the ``LightningModule``: ``segmenter`` and
    ``method.discriminators``) on batches of ``batch`` crops of ``crop`` = (H, W) px with
    ``workers`` data-loading processes, beyond what the process holds already."""
    segmenter: nn.Module = model.segmenter  # type: ignore[assignment]
    discriminators = list(getattr(getattr(model, "method", None), "discriminators", None) or ())
    params = sum(p.numel() for p in segmenter.parameters())
    params += sum(p.numel() for d in discriminators for p in d.parameters())
    activations = _meta_leaf_elements(segmenter, (batch, 3, *crop))
    classes = len(getattr(model, "class_names", ())) or 1
    for d in discriminators:
        channels = getattr(d.layers[0], "in_channels", classes)
        activations += _meta_leaf_elements(d, (batch, channels, *crop))
    tensors = FLOAT_BYTES * (PARAMETER_COPIES * params + ACTIVATION_COPIES * activations)
    return tensors + RUNTIME_BYTES + max(workers, 0) * WORKER_BYTES


def _crop(cfg: Any) -> tuple[tuple[int, int], str]:
    """The larger training crop of the two domains as (H, W), and its key."""
    best: tuple[tuple[int, int], str] = ((0, 0), "")
    for domain in ("source", "target"):
        crop = ((cfg.data.get(domain) or {}).get("transform") or {}).get("crop_size")
        if crop is None:
            continue
        sides = (crop, crop) if isinstance(crop, int) else tuple(crop)
        if len(sides) == 2 and sides[0] * sides[1] > best[0][0] * best[0][1]:
            best = ((int(sides[0]), int(sides[1])), f"data.{domain}.transform.crop_size")
    return best


def check_training_memory(model: nn.Module, cfg: Any) -> None:
    """One line before the first iteration when :func:`training_bytes` for the configured
    batch and crops exceeds the memory available (:func:`~uss_slam.core.resources.check_memory`).
    Skipped on a GPU and where the crops are not set (whole images: their size is the data's)."""
    accelerator = str(cfg.trainer.get("accelerator", "cpu"))
    if accelerator not in ("cpu", "auto") or (accelerator == "auto" and torch.cuda.is_available()):
        return
    crop, key = _crop(cfg)
    batch = cfg.data.get("batch_size")
    if not key or not isinstance(batch, int):
        return
    workers = cfg.data.get("num_workers")
    workers = workers if isinstance(workers, int) and workers > 0 else 0
    need = training_bytes(model, batch, crop, workers)
    log.info(estimate_line(need))
    net = str(cfg.model.net.get("_target_", "")).rsplit(".", 1)[-1]
    check_memory(
        need,
        f"data.batch_size={batch}, {key}={crop[0] if crop[0] == crop[1] else list(crop)}"
        + (f", data.num_workers={workers}" if workers else ""),
        f"training {net} (weights, gradients, the activations of one batch, the trainer"
        + (" and its data workers)" if workers else ")"),
        "data.batch_size or the crop size",
    )

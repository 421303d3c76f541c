"""Files that ship with the package: the pretrained init ``uss-demo`` starts every training from.

``deeplab_small_init.pt`` is a segmenter state dict (``backbone.* aux.* main.*``, float32) of the
small DeepLab-v2 (``model/net=deeplab_small``), trained source-only on the synthetic pretraining
set; ``README.md`` beside it says how it was made, its sha256 and its validation mIoU.
:func:`extract_segmenter` writes such a file from a ``uss-train`` checkpoint;
``model.net.weights_path=<file>`` loads it (:mod:`uss_slam.models.weights`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from uss_slam.core.errors import DataFormatError
from uss_slam.core.files import atomic_path, file_sha256

DEMO_INIT = "deeplab_small_init.pt"
"""The demo's init, a file of this package."""
SEGMENTER_PREFIX = "segmenter."


def demo_init_path() -> Path:
    """The installed path of :data:`DEMO_INIT` (a real file: the wheel is not zipped)."""
    return Path(str(resources.files(__name__) / DEMO_INIT))


@dataclass(frozen=True)
class ExtractedInit:
    """What :func:`extract_segmenter` wrote."""

    path: Path
    sha256: str
    tensors: int
    iteration: int | None  # the checkpoint's training iteration, when it records one


def extract_segmenter(checkpoint: str | Path, out: str | Path) -> ExtractedInit:
    """Write the segmenter of a ``uss-train`` checkpoint to ``out`` as a segmenter state dict:
    its ``state_dict``'s ``segmenter.*`` entries without the prefix, floating tensors as float32
    (no optimiser states, no discriminators: ~0.75 MB for ``deeplab_small`` instead of ~1.5).

    Raises:
        DataFormatError: naming ``checkpoint``: missing, unreadable, or without ``segmenter.*``.
    """
    import torch

    from uss_slam.models.checkpoint import load_checkpoint_file

    checkpoint = Path(checkpoint)
    blob = load_checkpoint_file(checkpoint)
    state = blob.get("state_dict") if isinstance(blob, dict) else None
    if not isinstance(state, dict):
        raise DataFormatError(checkpoint, "expected a uss-train checkpoint with a state_dict")
    segmenter = {
        key.removeprefix(SEGMENTER_PREFIX): (
            value.float() if value.is_floating_point() else value
        ).clone()  # own storage: a view would save the whole checkpoint's
        for key, value in state.items()
        if key.startswith(SEGMENTER_PREFIX)
    }
    if not segmenter:
        raise DataFormatError(checkpoint, "state_dict has no 'segmenter.*' entries")
    out = Path(out)
    buffer = io.BytesIO()
    torch.save(segmenter, buffer)
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(buffer.getvalue())
    iteration = blob.get("iteration")
    return ExtractedInit(
        out, file_sha256(out), len(segmenter), None if iteration is None else int(iteration)
    )

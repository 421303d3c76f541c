"""Checkpoints written atomically in their own folder.

Lightning's ``TorchCheckpointIO`` writes a local checkpoint through an fsspec transaction: a
temporary file in ``$TMPDIR``, moved onto the final name when complete. Where ``$TMPDIR`` is
another file system (a tmpfs ``/tmp``, a node-local scratch disk) that move is a copy, and a
full disk during the copy leaves a truncated ``best_iter*.ckpt`` under its final name while the
error names a temporary file that no longer exists. :class:`AtomicCheckpointIO` writes the
temporary file beside the final one, flushes it to the disk (``fsync``) and renames it: a
checkpoint is whole under its name or absent, and a full disk names the checkpoint's own path.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch
from lightning.fabric.plugins.io.torch_io import TorchCheckpointIO

from uss_slam.core.files import atomic_path


class AtomicCheckpointIO(TorchCheckpointIO):
    """``TorchCheckpointIO`` whose local saves are atomic in the checkpoint's folder
    (temporary ``.<name>.<random>.tmp`` beside it, ``fsync``, rename); remote URLs
    (``s3://...``) are saved as Lightning does."""

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None
    ) -> None:
        text = str(path)
        if storage_options is not None or ("://" in text and not text.startswith("file://")):
            super().save_checkpoint(checkpoint, path, storage_options)
            return
        final = Path(text.removeprefix("file://"))
        # a full disk: NoSpaceError naming ``final``, the temporary file removed
        with atomic_path(final) as tmp, open(tmp, "wb") as file:
            torch.save(checkpoint, file)
            file.flush()
            os.fsync(file.fileno())
        _fsync_folder(final.parent)


def _fsync_folder(folder: Path) -> None:
    """Flush the rename to the disk too (a power cut after it keeps the new name)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # file systems that cannot sync a folder
        pass
    finally:
        os.close(fd)

"""Helpers of the pipeline tests: a tiny ``uss-train`` run folder and a tiny ONNX segmenter of
the project's contract with known output."""

from __future__ import annotations

from pathlib import Path

import shared_helpers


def tiny_run(root: Path, seed: int = 0) -> Path:
    """A run folder of experiment ``tiny`` as ``uss-train`` writes it (``.hydra/config.yaml``
    with the demo's small net, ``checkpoints/last.ckpt``) with random weights and BatchNorm
    statistics (:func:`shared_helpers.fake_run` of :func:`shared_helpers.tiny_net`); returns
    the checkpoint."""
    return shared_helpers.fake_run(root, shared_helpers.tiny_net(seed), "tiny", iteration=3)


def colour_model(path: Path, bias: float = 128.0) -> Path:
    """:func:`shared_helpers.colour_segmenter`: an ONNX segmenter of the project's contract
    whose label is the argmax of ``(bias, R, G, B)`` per pixel."""
    return shared_helpers.colour_segmenter(path, bias)


def interrupt_at(iteration: int):  # noqa: ANN201 (a Lightning callback; lightning imported late)
    """A Lightning callback that raises ``KeyboardInterrupt`` before training iteration
    ``iteration`` (a stand-in for Ctrl-C or a kill once the checkpoints of the iterations before
    it are written). Named in a training override as ``pipeline_helpers.interrupt_at``."""
    from lightning.pytorch import Callback

    class InterruptAt(Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:  # noqa: ANN001
            if pl_module.iteration == iteration:
                raise KeyboardInterrupt

    return InterruptAt()

"""Adaptation methods, one file each, chosen by the config group ``model/method``.

A method computes the losses of one training iteration and steps the optimisers of the
LightningModule (:class:`~uss_slam.train.module.AdversarialSegmentation`), which owns the
segmenter, the discriminators (built only for a method that trains them), the schedules, logging
and checkpoints. To add one: subclass :class:`Method` in ``train/methods/<name>.py``; its
``training_step`` usually calls :func:`segmenter_step` with its :class:`TargetLoss` (and
:func:`discriminator_step` when it trains discriminators); add
``configs/model/method/<name>.yaml`` with its ``_target_``. That is all: the config group is the
list of methods (:mod:`uss_slam.train.method_configs`), which the experiment grid and the
every-method tests read.
"""

from uss_slam.train.methods.adaptsegnet import AdaptSegNet
from uss_slam.train.methods.advent import AdvEnt
from uss_slam.train.methods.base import (
    DomainPass,
    Method,
    NonFiniteLossError,
    SegmenterStep,
    SourceSegmentation,
    StepValues,
    TargetLoss,
    TrainBatch,
    can_batch_domains,
    check_finite,
    discriminator_scalars,
    discriminator_step,
    frozen,
    segmenter_step,
    uses_batch_statistics,
    weighted_heads,
)
from uss_slam.train.methods.minent import MinEnt
from uss_slam.train.methods.self_training import SelfTraining
from uss_slam.train.methods.source_only import SourceOnly

__all__ = [
    "AdaptSegNet",
    "AdvEnt",
    "DomainPass",
    "Method",
    "MinEnt",
    "NonFiniteLossError",
    "SegmenterStep",
    "SelfTraining",
    "SourceOnly",
    "SourceSegmentation",
    "StepValues",
    "TargetLoss",
    "TrainBatch",
    "can_batch_domains",
    "check_finite",
    "discriminator_scalars",
    "discriminator_step",
    "frozen",
    "segmenter_step",
    "uses_batch_statistics",
    "weighted_heads",
]

"""Adaptation methods, one file each, chosen by the config group ``model/method``.

A method computes the losses of one training iteration and steps the optimisers of the
LightningModule (:class:`~uss_slam.train.module.AdversarialSegmentation`), which owns the
segmenter, the discriminators, the schedules, logging and checkpoints. To add one: subclass
:class:`Method` in ``train/methods/<name>.py`` (using :class:`DomainPass`,
:class:`SourceSegmentation` and :func:`discriminator_step`) and add
``configs/model/method/<name>.yaml`` with its ``_target_``.
"""

from uss_slam.train.methods.adaptsegnet import AdaptSegNet
from uss_slam.train.methods.advent import AdvEnt
from uss_slam.train.methods.base import (
    DomainPass,
    Method,
    NonFiniteLossError,
    SourceSegmentation,
    StepValues,
    TrainBatch,
    can_batch_domains,
    check_finite,
    discriminator_scalars,
    discriminator_step,
    frozen,
    uses_batch_statistics,
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
    "SelfTraining",
    "SourceOnly",
    "SourceSegmentation",
    "StepValues",
    "TrainBatch",
    "can_batch_domains",
    "check_finite",
    "discriminator_scalars",
    "discriminator_step",
    "frozen",
    "uses_batch_statistics",
]

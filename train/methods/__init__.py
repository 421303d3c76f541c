"""Adaptation methods, one file each, chosen by the config group ``model/method``.

A method computes the losses of one training iteration and steps the optimisers of the
LightningModule (:class:`~uss_slam.train.module.AdversarialSegmentation`), which owns the
segmenter, its optimiser, the schedules, logging and checkpoints; the method owns what else it
trains (:class:`AdversarialMethod`: the two discriminators, their optimiser and the adversarial
weights). To add one: subclass :class:`Method` (or :class:`AdversarialMethod`) in
``train/methods/<name>.py``; its ``training_step`` usually calls :func:`segmenter_step` with its
:class:`TargetLoss`; add ``configs/model/method/<name>.yaml`` whose ``_target_`` names the class
(``uss_slam.train.methods.<name>.<Class>``). That is all: the config group is the list of
methods (:mod:`uss_slam.train.method_configs`), which the experiment grid and the every-method
tests read.
"""

from uss_slam.train.methods.adaptsegnet import AdaptSegNet
from uss_slam.train.methods.advent import AdvEnt
from uss_slam.train.methods.adversarial import AdversarialMethod, discriminator_scalars
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
    "AdversarialMethod",
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
    "frozen",
    "segmenter_step",
    "uses_batch_statistics",
    "weighted_heads",
]

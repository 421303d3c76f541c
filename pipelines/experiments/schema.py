"""The typed schema of ``configs/experiments.yaml`` (and the ``scale`` configs that fill it in):
every key ``uss-experiments`` reads, its type and its accepted values or range. Checked by
:func:`uss_slam.core.schema.check` before anything else; a bad value or an unknown key is one
line ``<key>: expected ..., got ...``; a list of names, seeds or depths takes each item once.
Rules across keys (a sequence of the other data kind, ``init.path`` for real data, a table
depth among the grid's) are :mod:`.experiment`'s and :mod:`.grid`'s.

``grid.loss``, ``grid.batchnorm`` and ``grid.method_overrides`` are the user's mappings (a loss
weight, a method name as keys): open here, checked by the grid. ``launcher`` is a Hydra
launcher group of its own (its ``n_jobs`` rule: :func:`.experiment.check_parallelism`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from uss_slam.core.ranges import MAX_REPEATS, MAX_SEED
from uss_slam.core.schema import MAX_THREADS, ranged
from uss_slam.pipelines.runs import CHECKPOINT_POLICIES
from uss_slam.pipelines.synthetic_data import SHIFTS
from uss_slam.synthetic.textures import WARDROBES

from .grid import (
    METHODS,
    N_LAYERS_RANGE,
    SYNTHETIC_SEQUENCES,
    SYSTEMS,
    TUM_SEQUENCES,
    VARIANTS,
    discriminator_methods,
)

# OmegaConf reads Optional[...] (not X | None) in a dataclass schema.
# ruff: noqa: UP045

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
STAGES = ("data", "train", "export", "slam", "tables")
INIT_KINDS = ("scratch", "pretrained")
"""``init.kind``: ``scratch`` (every training from random weights) or ``pretrained`` (every
training from a pretrained init: ``init.path``, or one trained on a synthetic pretraining set)."""
INIT_STYLES = ("source", "mixed")
"""``init.style``: the synthetic pretraining set's lighting and camera (``source``: the source
domain's only, the real regime; ``mixed``: half in the target's, the earlier tables' init)."""
INIT_REGIMES = ("real", "legacy")
"""``init.regime``: what the tables claim (``real`` needs ``init.style=source``)."""
EXPERIMENTS = tuple(sorted(p.stem for p in (CONFIG_DIR / "experiment").glob("*.yaml")))
"""The ``uss-train`` experiments a training may start from (``train.experiment``)."""
DEPTHS = {"min": N_LAYERS_RANGE.start, "max": N_LAYERS_RANGE.stop - 1}


def _names(name: str, values: Any) -> type[enum.Enum]:
    """An Enum whose members are ``values`` (a list element of one of these names)."""
    return enum.Enum(name, {str(v): str(v) for v in dict.fromkeys(values)})  # type: ignore[return-value]


Stage = _names("Stage", STAGES)
Method = _names("Method", METHODS)
DiscriminatorMethod = _names("DiscriminatorMethod", discriminator_methods())
Sequence = _names("Sequence", (*SYNTHETIC_SEQUENCES, *TUM_SEQUENCES))
TumSequence = _names("TumSequence", TUM_SEQUENCES)
VariantName = _names("VariantName", VARIANTS)
System = _names("System", SYSTEMS)


MAX_RENDERS = 100_000
"""The most images or frames one synthetic data set renders (about a day on two cores at the
rendering speed of the quick scale; PASCAL VOC's augmented training set has 10582)."""


@dataclass
class SyntheticData:
    seed: int = ranged(0, min=0, max=MAX_SEED)
    voc_images: int = ranged(400, min=1, max=MAX_RENDERS)
    voc_size: str = ranged("320x240", text=True)  # WxH: parsed by the experiment's checks
    shift: str = ranged("tum_like", choices=SHIFTS)
    source_outfits: Optional[str] = ranged(None, choices=(*WARDROBES, None))
    train_frames: int = ranged(100, min=2, max=MAX_RENDERS)
    val_frames: int = ranged(100, min=2, max=MAX_RENDERS)
    train_size: str = ranged("320x240", text=True)
    eval_frames: int = ranged(300, min=2, max=MAX_RENDERS)
    eval_size: str = ranged("640x480", text=True)
    eval_seed: int = ranged(1000, min=0, max=MAX_SEED)


@dataclass
class RealData:
    voc: Optional[str] = None
    sbd: Optional[str] = None
    coco: Optional[str] = None
    tum: Optional[str] = None
    target: list[TumSequence] = field(default_factory=list)  # type: ignore[valid-type]


@dataclass
class Data:
    kind: str = ranged("synthetic", choices=("synthetic", "real"))
    synthetic: SyntheticData = field(default_factory=SyntheticData)
    real: RealData = field(default_factory=RealData)


@dataclass
class Init:
    kind: str = ranged("scratch", choices=INIT_KINDS)
    style: str = ranged("source", choices=INIT_STYLES)
    regime: str = ranged("real", choices=INIT_REGIMES)
    seeds: list[int] = ranged(
        default_factory=lambda: [0], min=0, max=MAX_SEED, nonempty=True, unique=True
    )
    images: int = ranged(800, min=2)
    size: str = ranged("320x240", text=True)
    render_seed: int = ranged(900, min=0, max=MAX_SEED)
    experiment: str = ranged("pretrain", choices=EXPERIMENTS)
    overrides: list[str] = field(default_factory=list)
    path: Optional[str] = None


@dataclass
class Train:
    experiment: str = ranged("ci", choices=EXPERIMENTS)
    overrides: list[str] = field(default_factory=list)
    num_threads: Optional[int] = ranged(None, min=1, max=MAX_THREADS)
    checkpoint: str = ranged("last", choices=tuple(CHECKPOINT_POLICIES))


@dataclass
class Grid:
    methods: list[Method] = ranged(  # type: ignore[valid-type]
        default_factory=lambda: ["source_only", "adaptsegnet"], nonempty=True
    )
    n_layers: list[int] = ranged(
        default_factory=lambda: [4, 5, 6, 7], nonempty=True, unique=True, **DEPTHS
    )
    depth_sweep: list[DiscriminatorMethod] = field(  # type: ignore[valid-type]
        default_factory=lambda: ["adaptsegnet"]
    )
    seeds: list[int] = ranged(
        default_factory=lambda: [0, 1, 2], min=0, max=MAX_SEED, nonempty=True, unique=True
    )
    loss: dict[str, Any] = field(default_factory=dict)
    batchnorm: Optional[dict[str, Any]] = None
    method_overrides: Optional[dict[str, Any]] = None
    adabn: bool = True
    adabn_methods: list[Method] = ranged(  # type: ignore[valid-type]
        default_factory=lambda: ["source_only"], nonempty=True, needs="adabn"
    )
    oracle: Optional[bool] = None


@dataclass
class CrfParams:
    """Types only: the ranges are the dense CRF's own (``DenseCrf.from_config``, shared with
    uss-slam's ``segmenter.crf_params``)."""

    iterations: Optional[int] = None
    gaussian_sxy: Optional[float] = None
    gaussian_compat: Optional[float] = None
    bilateral_sxy: Optional[float] = None
    bilateral_srgb: Optional[float] = None
    bilateral_compat: Optional[float] = None


@dataclass
class OrbSlam3:
    vocabulary: Optional[str] = None
    repeats: int = ranged(3, min=1, max=MAX_REPEATS)
    overrides: list[str] = field(default_factory=list)


@dataclass
class Slam:
    overrides: list[str] = field(default_factory=list)
    repeats: int = ranged(3, min=1, max=MAX_REPEATS)
    every_model: bool = False
    orbslam3: OrbSlam3 = field(default_factory=OrbSlam3)


@dataclass
class SegEval:
    stride: int = ranged(5, min=1)
    threads: Optional[int] = ranged(1, min=1, max=MAX_THREADS)
    source_val_stride: Optional[int] = ranged(1, min=1)


@dataclass
class Tables:
    n_layers: Optional[int] = ranged(5, **DEPTHS)


@dataclass
class ExperimentsSchema:
    """``configs/experiments.yaml``: see that file for what each key does."""

    scale_name: str = ranged("custom", text=True)
    out_dir: str = "outputs/experiments/custom"
    stages: list[Stage] = ranged(default_factory=lambda: list(STAGES), nonempty=True)  # type: ignore[valid-type]
    dry_run: bool = False
    fast_dev_run: bool = False
    data: Data = field(default_factory=Data)
    init: Init = field(default_factory=Init)
    train: Train = field(default_factory=Train)
    grid: Grid = field(default_factory=Grid)
    sequences: list[Sequence] = ranged(  # type: ignore[valid-type]
        default_factory=lambda: ["walking_xyz"], nonempty=True
    )
    variants: list[VariantName] = ranged(  # type: ignore[valid-type]
        default_factory=lambda: ["none", "semantic"], nonempty=True
    )
    crf_params: CrfParams = field(default_factory=CrfParams)
    systems: list[System] = ranged(default_factory=lambda: ["harness"], nonempty=True)  # type: ignore[valid-type]
    slam: Slam = field(default_factory=Slam)
    segeval: SegEval = field(default_factory=SegEval)
    tables: Tables = field(default_factory=Tables)
    launcher: Any = None  # a Hydra launcher group (configs/launcher/); its own rules

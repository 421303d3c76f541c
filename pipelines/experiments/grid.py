"""The experiment grid of ``uss-experiments``: which trainings, segmentation evaluations and SLAM
runs a configuration asks for, each with the stable id that names its folder under ``out_dir``.

Pure Python (no torch, no Hydra): the grid is expanded and checked before any work starts, so a
bad key (unknown method, sequence, variant, system) is one error line naming the key and the
accepted values.

Ids (= folders under ``out_dir``)::

    train/<config>_s<seed>                         one training (config = method [+ _n<n>] [+ loss]
                                                   [+ _bn<mode>] [+ _i<k>]) (_n<n>: methods with
                                                   discriminators; _bn<mode>: grid.batchnorm;
                                                   _i<k>: init k, with more than one init seed)
    train/oracle_s<seed>                           T0's target oracle (labelled target frames)
    exports/adabn[<loss>]_s<seed>                  source-only's checkpoint with target BatchNorm
                                                   statistics (AdaBN; an export, not a training)
    segeval/<model>                                a model's segmentation metrics on every sequence
    segeval/crf/<model>                            the same with the dense CRF (the *_crf variants)
    segeval/source_val/<model>                     T0's in-domain column: the source val split
    slam/<system>/<sequence>/<variant>             a model-free SLAM run (no filter, geometry, oracle)
    slam/<system>/<sequence>/<variant>/<model>     a SLAM run with an exported model
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from importlib.resources import files
from pathlib import Path
from typing import Any, ClassVar

import yaml

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.pipelines.runs import USES_TARGET_LABELS
from uss_slam.slam_eval.filters.build import filter_classes
from uss_slam.slam_eval.variants import Variant, check_filters, masks_orbslam3_input
from uss_slam.slam_eval.variants import read_table as read_variants
from uss_slam.train.method_configs import method_names, trains_discriminators

from .keys import (
    check_sequences,
    choose,
    given,
    loss_combinations,
    non_empty_list,
    source_val_stride,
    unique,
)

METHODS: dict[str, tuple[str, ...]] = {name: (f"model/method={name}",) for name in method_names()}
"""``uss-train`` overrides of each shipped adaptation method: every option of the config group
``model/method`` (source-only, the "without ATL" baseline, first; then the others)."""
ORACLE = "oracle"
"""T0's target oracle: source-only trained on the *labelled* target training frames (the same
net, budget and crops; ``grid.oracle``). Not a method of ``grid.methods``: its data overrides are
the plan's (:func:`uss_slam.pipelines.experiments.plan.oracle_overrides`)."""
ADABN = "adabn"
"""T0's AdaBN row: each source-only checkpoint with BatchNorm statistics of target training
frames (``grid.adabn``), exported and scored as a model of its own."""
REFERENCE_METHODS: dict[str, tuple[str, ...]] = {ORACLE: ("model/method=source_only",)}
"""The ``uss-train`` overrides of T0's reference trainings (besides the plan's data ones)."""
ADAPTED = "adaptsegnet"
"""The paper's adapted model: the "with ATL" side of T2 / T3 and the downstream ratio."""


def discriminator_methods() -> tuple[str, ...]:
    """Methods with discriminators (their class's ``trains_discriminators``): trained at a
    discriminator depth (every depth of ``grid.n_layers`` when listed in ``grid.depth_sweep``,
    else ``tables.n_layers`` only), and the only ones the adversarial loss weights of
    ``grid.loss`` apply to."""
    return tuple(m for m in METHODS if trains_discriminators(m))


DEPTH_SWEEP = (ADAPTED,)
"""``grid.depth_sweep`` when not given: the paper sweeps the depth of AdaptSegNet's
discriminators; the other methods are compared at the tables' depth."""
ADVERSARIAL_LOSS_KEYS = ("lambda_adv_aux", "lambda_adv_main")
"""The weights of ``grid.loss`` that are the adversarial methods' own (``model.method.<key>``);
the others weight the source loss of every method (``model.loss.<key>``)."""


def loss_key(key: str) -> str:
    """The ``uss-train`` key of a ``grid.loss`` weight."""
    return f"model.method.{key}" if key in ADVERSARIAL_LOSS_KEYS else f"model.loss.{key}"


N_LAYERS_RANGE = range(1, 9)
"""Discriminator depths the grid accepts (the paper sweeps 4..7)."""

SYSTEMS = ("harness", "orbslam3")

SHIFT_METHOD_SETTINGS = "shift_method_settings.yaml"
"""Each shift preset's method settings, in the ``uss_slam.configs`` tree."""


def read_shift_method_settings() -> dict[str, dict[str, tuple[str, ...]]]:
    """``{shift preset: {method: its uss-train overrides}}`` from
    ``configs/shift_method_settings.yaml`` (``grid.method_overrides`` when not given)."""
    where = f"configs/{SHIFT_METHOD_SETTINGS}"
    node = yaml.safe_load(
        files("uss_slam.configs").joinpath(SHIFT_METHOD_SETTINGS).read_text(encoding="utf-8")
    )
    if not isinstance(node, dict):
        raise DataFormatError(Path(where), "expected a mapping of shift presets")
    table: dict[str, dict[str, tuple[str, ...]]] = {}
    for shift, methods in node.items():
        if not isinstance(methods, dict) or not all(
            isinstance(o, list) and all(isinstance(x, str) for x in o) for o in methods.values()
        ):
            raise DataFormatError(
                Path(where), f"{shift}: expected a mapping of methods to lists of overrides"
            )
        table[str(shift)] = {str(m): tuple(o) for m, o in methods.items()}
    return table


PRESET_METHOD_OVERRIDES: dict[str, dict[str, tuple[str, ...]]] = read_shift_method_settings()
"""Each shift preset's method settings (``configs/shift_method_settings.yaml``)."""


TARGET_LABEL_USES = ("training", "settings", "checkpoint selection")
"""What of a model was chosen with target labels (``runs.csv`` column ``target_labels``, ``;``
between them; the tables mark its rows †): the oracle's training, method settings of
:data:`PRESET_METHOD_OVERRIDES` (chosen on labelled target validation frames), a checkpoint
policy that reads them (``train.checkpoint=best_target_val``)."""


def target_label_uses(cfg: Mapping[str, Any], cell: TrainCell) -> tuple[str, ...]:
    """What of training ``cell`` the config ``cfg`` chose with target labels
    (:data:`TARGET_LABEL_USES`): settings count when one of them is the synthetic shift preset's
    for that method, whether by ``grid.method_overrides: null`` or written out."""
    data = cfg.get("data") or {}
    shift = (data.get("synthetic") or {}).get("shift", "tum_like")
    preset = PRESET_METHOD_OVERRIDES.get(str(shift), {}) if data.get("kind") == "synthetic" else {}
    policy = str((cfg.get("train") or {}).get("checkpoint") or "last")
    uses = ["training"] if cell.method == ORACLE else []
    uses += ["settings"] if set(cell.settings) & set(preset.get(cell.method, ())) else []
    uses += ["checkpoint selection"] if policy in USES_TARGET_LABELS else []
    return tuple(uses)


VARIANTS: dict[str, Variant] = read_variants()
"""The variants by name, in the tables' order (``configs/variants.yaml``; its filters are
checked against the filter nodes when the experiment is checked, :func:`check_variant_filters`)."""

SYSTEM_VARIANTS: dict[str, tuple[str, ...]] = {
    "harness": tuple(VARIANTS),
    # ORB-SLAM3 gets the image with the dynamic pixels blanked out: only the variants whose
    # filters find them in the frame alone apply (the geometry and object checks need the
    # harness's map)
    "orbslam3": tuple(n for n, v in VARIANTS.items() if masks_orbslam3_input(v)),
}


def check_variant_filters() -> None:
    """Every filter of ``configs/variants.yaml`` is a filter node; else one line."""
    check_filters(VARIANTS, list(filter_classes()))


SYNTHETIC_SEQUENCES = (
    "walking_xyz",
    "walking_static",
    "walking_rpy",
    "walking_halfsphere",
    "sitting_static",
    "static_xyz",
)
"""Evaluation sequences of synthetic data (``uss-synth`` presets)."""

TUM_SEQUENCES = tuple(
    f"{people}_{motion}"
    for people in ("walking", "sitting")
    for motion in ("xyz", "static", "rpy", "halfsphere")
)
"""Evaluation sequences of real data: TUM RGB-D fr3 ``rgbd_dataset_freiburg3_<name>``."""


def _short(value: float) -> str:
    return f"{value:g}"


class _ModelNames:
    """The names of a model (:data:`Model`): ``<config>_s<seed>``, and its id
    ``<folder>/<config>_s<seed>`` (``folder``: ``train`` or ``exports``)."""

    folder: ClassVar[str]

    @property
    def model(self) -> str:
        return f"{self.config}_s{self.seed}"

    @property
    def id(self) -> str:
        return f"{self.folder}/{self.model}"


@dataclass(frozen=True)
class TrainCell(_ModelNames):
    """One training of the grid."""

    folder: ClassVar[str] = "train"
    method: str
    seed: int
    n_layers: int | None = None  # methods with discriminators only
    loss: tuple[tuple[str, float], ...] = ()  # (key, value) pinned for this training
    tag: str = ""  # loss suffix of the config name when the grid varies the loss weights
    settings: tuple[str, ...] = ()  # the method's own uss-train overrides (grid.method_overrides)
    target_labels: tuple[str, ...] = ()  # what was chosen with them (TARGET_LABEL_USES; no key)
    batchnorm: str | None = None  # model.net.batchnorm of this training (grid.batchnorm)
    init: int | None = None  # the pretrained init's seed (init.seeds; None: scratch or init.path)
    init_tag: bool = False  # the config names the init (more than one init seed)

    @property
    def config(self) -> str:
        """The configuration the tables aggregate over seeds: method, depth, loss weights,
        BatchNorm mode, init."""
        name = self.method if self.n_layers is None else f"{self.method}_n{self.n_layers}"
        bn = "" if self.batchnorm is None else f"_bn{self.batchnorm}"
        return f"{name}{self.tag}{bn}{f'_i{self.init}' if self.init_tag else ''}"

    def overrides(self) -> list[str]:
        """The cell's own ``uss-train`` overrides (after the scale's)."""
        method = METHODS.get(self.method) or REFERENCE_METHODS[self.method]
        out = [*method, *self.settings, f"seed={self.seed}", f"run_name={self.model}"]
        if self.n_layers is not None:
            out.append(f"model.method.discriminator.n_layers={self.n_layers}")
        out += [f"{loss_key(k)}={_short(v)}" for k, v in self.loss]
        if self.batchnorm is not None:
            out.append(f"model.net.batchnorm={self.batchnorm}")
        return out

    def describe(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "n_layers": self.n_layers,
            "loss": ";".join(f"{k}={_short(v)}" for k, v in self.loss),
            "config": self.config,
            "seed": self.seed,
            "target_labels": ";".join(self.target_labels) or None,
            "init": self.init,
            "batchnorm": self.batchnorm,
        }


@dataclass(frozen=True)
class AdaBNCell(_ModelNames):
    """AdaBN (Li et al. 2016): the export of training ``source`` (source-only, or a method of
    ``grid.adabn_methods``) with its BatchNorm statistics recomputed on unlabelled target
    training frames; a model, not a training. Named ``adabn[<loss>]`` for source-only (T0's
    AdaBN row) and ``<config>_adabn`` for a method's checkpoint."""

    folder: ClassVar[str] = "exports"
    source: TrainCell

    @property
    def config(self) -> str:
        if self.source.method != "source_only":
            return f"{self.source.config}_{ADABN}"
        return ADABN + self.source.config.removeprefix(self.source.method)

    @property
    def seed(self) -> int:
        return self.source.seed

    def describe(self) -> dict[str, Any]:
        return {**self.source.describe(), "method": ADABN, "config": self.config}


Model = TrainCell | AdaBNCell
"""Something exported and scored: a training's checkpoint, or an AdaBN export of one."""


@dataclass(frozen=True)
class SlamCell:
    """One SLAM run: a system on a sequence with a variant (and a model when it needs one)."""

    system: str
    sequence: str
    variant: str
    model: Model | None = None

    @property
    def id(self) -> str:
        base = f"slam/{self.system}/{self.sequence}/{self.variant}"
        return base if self.model is None else f"{base}/{self.model.model}"


@dataclass(frozen=True)
class SegEvalCell:
    """The segmentation metrics of one model on every evaluation sequence (with the dense CRF
    of the ``*_crf`` variants when ``crf``), or with ``source_val`` on the source validation
    split (T0's in-domain column)."""

    model: Model
    crf: bool = False
    source_val: bool = False

    @property
    def id(self) -> str:
        if self.source_val:
            return f"segeval/source_val/{self.model.model}"
        return f"segeval/{'crf/' if self.crf else ''}{self.model.model}"


@dataclass(frozen=True)
class Grid:
    trainings: tuple[TrainCell, ...]
    segevals: tuple[SegEvalCell, ...]
    slams: tuple[SlamCell, ...]
    sequences: tuple[str, ...]
    systems: tuple[str, ...]
    variants: tuple[str, ...]
    table_configs: tuple[str, ...] = field(default=())
    """Configs of T2 / T3 / the downstream ratio: source-only and the adapted one of ``n``."""
    batchnorm: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """``grid.batchnorm``: method -> the BatchNorm modes it is trained in."""
    adabn: tuple[AdaBNCell, ...] = ()
    """T0's AdaBN exports (``grid.adabn``): one per training of ``grid.adabn_methods``
    (source-only by default) at the tables' depth."""

    @property
    def models(self) -> tuple[Model, ...]:
        """Everything exported and scored: the trainings, then the AdaBN exports."""
        return (*self.trainings, *self.adabn)

    def model(self, name: str) -> Model:
        for cell in self.models:
            if cell.model == name:
                return cell
        raise KeyError(name)

    def training(self, model: str) -> TrainCell:
        """The training a model comes from (an AdaBN export's: its source-only training)."""
        cell = self.model(model)
        return cell.source if isinstance(cell, AdaBNCell) else cell


def _loss_tag(combo: tuple[tuple[str, float], ...], varied: set[str]) -> str:
    """``_adv_main0.001`` for each varied key (the config name only shows what changes)."""
    return "".join(f"_{k.removeprefix('lambda_')}{_short(v)}" for k, v in combo if k in varied)


def method_overrides(values: Any) -> dict[str, tuple[str, ...]]:
    """``grid.method_overrides``: a mapping of method to a list of ``uss-train`` overrides
    (``key=value`` strings), for methods of :data:`METHODS` or the oracle; a method the grid
    does not train may be listed (its settings are then unused)."""
    if values is None:
        return {}
    if not isinstance(values, Mapping):
        raise UssSlamError(
            f"grid.method_overrides: expected a mapping of method to a list of uss-train "
            f"overrides, got {values!r}"
        )
    out: dict[str, tuple[str, ...]] = {}
    for method, listed in values.items():
        choose("grid.method_overrides", method, (*METHODS, ORACLE))
        key = f"grid.method_overrides.{method}"
        if listed is None:
            continue
        if isinstance(listed, (str, bytes)) or not isinstance(listed, Sequence):
            raise UssSlamError(f"{key}: expected a list of key=value overrides, got {listed!r}")
        for item in listed:
            if not isinstance(item, str) or "=" not in item or item.startswith("="):
                raise UssSlamError(f"{key}: expected key=value overrides, got {item!r}")
        out[str(method)] = tuple(listed)
    return out


def batchnorm_modes(values: Any) -> dict[str, tuple[str, ...]]:
    """``grid.batchnorm``: a mapping of method to the ``model.net.batchnorm`` modes it is
    trained in, one training row each (``_bn<mode>`` in its config) instead of its row in the
    network's own mode; a method not listed keeps its network's mode. The modes are checked
    against the network by
    :func:`uss_slam.pipelines.experiments.experiment.check_batchnorm`."""
    if values is None:
        return {}
    if not isinstance(values, Mapping):
        raise UssSlamError(
            f"grid.batchnorm: expected a mapping of method to a list of BatchNorm modes "
            f"({{adaptsegnet: [trained, reference]}}), got {values!r}"
        )
    out: dict[str, tuple[str, ...]] = {}
    for method, listed in values.items():
        choose("grid.batchnorm", method, METHODS)
        key = f"grid.batchnorm.{method}"
        modes = non_empty_list(key, [listed] if isinstance(listed, str) else listed)
        for mode in modes:
            if not isinstance(mode, str) or not mode.isidentifier():
                raise UssSlamError(f"{key}: expected BatchNorm mode names, got {mode!r}")
        unique(key, modes)
        out[str(method)] = tuple(modes)
    return out


def _depth(key: str, n: Any, what: str = "integers") -> int:
    if isinstance(n, bool) or not isinstance(n, int) or n not in N_LAYERS_RANGE:
        raise UssSlamError(
            f"{key}: expected {what} {N_LAYERS_RANGE.start}..{N_LAYERS_RANGE.stop - 1}, got {n!r}"
        )
    return n


def training_cells(
    grid: Mapping[str, Any], n_table: Any = None, inits: Sequence[int | None] = (None,)
) -> list[TrainCell]:
    """The trainings of ``grid`` (``methods``, ``n_layers``, ``depth_sweep``, ``seeds``,
    ``loss``, ``batchnorm``), in table order: per method in the order listed, every BatchNorm
    mode of ``batchnorm``, every init of ``inits`` (``init.seeds``; ``None``: no init to tell
    apart), every seed. A method with discriminators is trained once per depth of ``n_layers``
    when ``depth_sweep`` lists it, else at ``n_table`` (``tables.n_layers``) only. The values
    are the schema's (:class:`.schema.Grid`: methods, depths, seeds, each once); the rules
    across keys are checked here."""
    methods = [str(m) for m in grid["methods"]]
    sweep = [str(m) for m in grid.get("depth_sweep", DEPTH_SWEEP)]
    with_discriminators = discriminator_methods()
    seeds = list(grid["seeds"])
    depths: list[int] = []
    if any(m in sweep for m in methods):
        depths = list(grid["n_layers"])
        if n_table is not None and n_table not in depths:
            raise UssSlamError(
                f"tables.n_layers: {n_table!r} is not a depth of the grid; accepted: "
                f"{', '.join(map(str, depths))}"
            )
    if any(m in with_discriminators and m not in sweep for m in methods):
        _depth("tables.n_layers", n_table, "a discriminator depth")
    combos = loss_combinations(grid.get("loss"))
    varied = {k for k in given(grid.get("loss")) if len({dict(c)[k] for c in combos}) > 1}
    settings = method_overrides(grid.get("method_overrides"))
    modes = batchnorm_modes(grid.get("batchnorm"))
    tagged = len(inits) > 1
    cells: list[TrainCell] = []
    for method in methods:
        adversarial = method in with_discriminators
        method_combos: list[tuple[tuple[str, float], ...]] = []
        for combo in combos:
            # Methods without discriminators never use the adversarial weights: one training
            # per seg-loss setting.
            kept = (
                combo
                if adversarial
                else tuple(kv for kv in combo if kv[0] not in ADVERSARIAL_LOSS_KEYS)
            )
            if kept not in method_combos:
                method_combos.append(kept)
        method_depths = (depths if method in sweep else [n_table]) if adversarial else [None]
        for n in method_depths:
            for combo in method_combos:
                tag = _loss_tag(combo, varied)
                for bn in modes.get(method, (None,)):
                    for init in inits:
                        cells += [
                            TrainCell(
                                method,
                                int(seed),
                                n,
                                combo,
                                tag,
                                settings.get(method, ()),
                                batchnorm=bn,
                                init=init,
                                init_tag=tagged,
                            )  # fmt: skip
                            for seed in seeds
                        ]
    return cells


def expand(
    cfg: Mapping[str, Any],
    accepted_sequences: Sequence[str],
    inits: Sequence[int | None] = (None,),
) -> Grid:
    """The whole grid of a (resolved, plain-container) ``uss-experiments`` config; ``inits``:
    the pretrained inits every training is repeated from (``init.seeds``; one ``None``: a single
    start, scratch or ``init.path``)."""
    n_table = (cfg.get("tables") or {}).get("n_layers")
    trainings = training_cells(cfg["grid"], n_table, inits)
    # T0's reference rows: the target oracle (one more training per seed) and AdaBN (an export
    # of each source-only training); absent keys = off (configs/experiments.yaml turns them on)
    if cfg["grid"].get("oracle"):
        oracle_settings = method_overrides(cfg["grid"].get("method_overrides")).get(ORACLE, ())
        trainings += [
            TrainCell(ORACLE, int(s), settings=oracle_settings, init=i, init_tag=len(inits) > 1)
            for i in inits
            for s in cfg["grid"]["seeds"]
        ]
    trainings = [replace(t, target_labels=target_label_uses(cfg, t)) for t in trainings]
    adabn_methods = [str(m) for m in cfg["grid"].get("adabn_methods", ["source_only"])]
    adabn = [
        AdaBNCell(t)
        for t in trainings
        if t.method in adabn_methods and t.n_layers in (None, n_table) and cfg["grid"].get("adabn")
    ]
    models: list[Model] = [*trainings, *adabn]
    sequences = check_sequences(cfg.get("sequences"), accepted_sequences)
    systems = [str(s) for s in cfg["systems"]]
    variants = [str(v) for v in cfg["variants"]]
    if n_table is None and any(t.n_layers is not None for t in trainings):
        raise UssSlamError("tables.n_layers: missing; expected a depth of grid.n_layers")
    table_configs = list(
        dict.fromkeys(
            t.config
            for t in trainings
            if t.method in ("source_only", ADAPTED) and t.n_layers in (None, n_table)
        )
    )
    every_model = bool((cfg.get("slam") or {}).get("every_model", False))
    slams: list[SlamCell] = []
    for system in systems:
        for sequence in sequences:
            for name in variants:
                if name not in SYSTEM_VARIANTS[system]:
                    continue
                variant = VARIANTS[name]
                if variant.segmenter != "model":
                    slams.append(SlamCell(system, sequence, name))
                    continue
                for cell in models:
                    # semantic runs for every model (T1, T0); the geometry and CRF variants for
                    # the models the tables compare (T2, T3), unless slam.every_model; and
                    # semantic+geometry for T0's AdaBN rows too: the baseline any method must
                    # beat, in the downstream ratio of both its filters
                    if (
                        name == "semantic"
                        or every_model
                        or cell.config in table_configs
                        or (isinstance(cell, AdaBNCell) and name == "semantic_geometry")
                    ):
                        slams.append(SlamCell(system, sequence, name, cell))
    segevals = [SegEvalCell(m) for m in models]
    if any(VARIANTS[v].crf for v in variants):
        # the CRF's segmentation metrics for the models that have CRF runs
        segevals += [
            SegEvalCell(m, crf=True) for m in models if every_model or m.config in table_configs
        ]
    if source_val_stride(cfg) is not None:
        # T0's in-domain column, for T0's rows: every model at the tables' depth
        segevals += [
            SegEvalCell(m, source_val=True)
            for m in models
            if isinstance(m, AdaBNCell) or m.n_layers in (None, n_table)
        ]
    return Grid(
        batchnorm=batchnorm_modes(cfg["grid"].get("batchnorm")),
        trainings=tuple(trainings),
        segevals=tuple(segevals),
        slams=tuple(slams),
        sequences=tuple(sequences),
        systems=tuple(systems),
        variants=tuple(variants),
        table_configs=tuple(table_configs),
        adabn=tuple(adabn),
    )

"""The checked configuration of ``uss-experiments``: every key that can be wrong is checked here,
before any work starts, and named in a one-line error with the accepted values. Types, ranges,
choices and unknown keys are the schema's (:mod:`.schema`); what is left here are the rules
across keys and what needs the file system or an installed package."""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from uss_slam.core.cli import warning
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import saved_by_torch
from uss_slam.core.paths import input_file, input_folder
from uss_slam.core.ranges import MAX_THREADS, THREADS_PER_CPU, machine_threads
from uss_slam.core.schema import changed_keys, unused_line, unused_settings
from uss_slam.core.schema import check as check_schema

from .grid import (
    PRESET_METHOD_OVERRIDES,
    SYNTHETIC_SEQUENCES,
    TUM_SEQUENCES,
    VARIANTS,
    Grid,
    check_variant_filters,
    expand,
)
from .keys import check_sequences, choose, given
from .schema import CONFIG_DIR, INIT_KINDS, STAGES, ExperimentsSchema

__all__ = ["CONFIG_DIR", "INIT_KINDS", "STAGES", "Experiment", "Init", "check"]

LAUNCHERS = ("basic", "joblib", "submitit_local", "submitit_slurm")
TUM_PREFIX = "rgbd_dataset_freiburg3_"
"""The folder name of a TUM RGB-D fr3 sequence before its name (``data.real.target``)."""


def check_choices(argv: Sequence[str]) -> None:
    """Unknown ``scale=`` / ``launcher=`` options: one line naming the key and the accepted
    values (before Hydra, which would print a multi-line error)."""
    folders = [CONFIG_DIR, *_config_dirs(argv)]  # a user's own options (--config-dir DIR)
    for arg in argv:
        key, sep, value = arg.lstrip("+~").partition("=")
        if sep and key in ("scale", "launcher"):
            accepted = sorted({p.stem for f in folders for p in (Path(f) / key).glob("*.yaml")})
            choose(key, value, accepted)


def _config_dirs(argv: Sequence[str]) -> list[str]:
    """The folders ``--config-dir DIR`` / ``-cd DIR`` (or ``--config-dir=DIR``) add to Hydra's
    search path."""
    found = []
    for i, arg in enumerate(argv):
        if arg in ("--config-dir", "-cd") and i + 1 < len(argv):
            found.append(argv[i + 1])
        elif arg.startswith("--config-dir="):
            found.append(arg.partition("=")[2])
    return found


def _size(key: str, text: Any) -> str:
    from uss_slam.synthetic.output import SynthArgumentError, parse_size

    try:
        parse_size(str(text))
    except SynthArgumentError as error:
        raise UssSlamError(f"{key}: {error}") from None
    return str(text)


@dataclass(frozen=True)
class Init:
    """The checked ``init`` section: where every training of the grid starts from."""

    kind: str
    seeds: tuple[int, ...] = ()  # one init per seed (synthetic pretraining only)
    style: str = "source"  # the pretraining set's lighting: source | mixed (init.style)
    regime: str = "real"  # what the tables claim: real | legacy (init.regime)
    images: int = 0  # the pretraining set: images, size, uss-synth seed
    size: str = ""
    render_seed: int = 0
    experiment: str = ""  # the uss-train experiment of the pretraining
    overrides: tuple[str, ...] = ()  # more uss-train overrides of the pretraining
    path: Path | None = None  # a user's pretrained file (no pretraining runs)

    @property
    def pretrained(self) -> bool:
        return self.kind == "pretrained"

    @property
    def pretrains(self) -> bool:
        """True when the data stage trains the init(s) on a synthetic pretraining set."""
        return self.pretrained and self.path is None


@dataclass
class Experiment:
    """The checked configuration: everything the stages need."""

    cfg: dict[str, Any]
    out: Path
    grid: Grid
    stages: tuple[str, ...]
    synthetic: bool
    launcher: dict[str, Any]
    missing_launcher_keys: list[str]
    init: Init = field(default_factory=lambda: Init("scratch"))
    """The warm-start protocol (``init``): where every training starts from."""
    train_specs: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Training id -> its job spec (set when the trainings are planned)."""

    @property
    def fast(self) -> bool:
        return bool(self.cfg.get("fast_dev_run"))


def training_seeds(seed: int) -> set[int]:
    """The seeds of the synthetic training data (VOC set, target training sequences,
    validation sequences): the evaluation sequences' seeds must differ from all of them."""
    from uss_slam.pipelines.synthetic_data import sequence_seeds

    return {seed, *sequence_seeds(seed).values()}


def warn_orbslam3_unused(orb: Mapping[str, Any]) -> None:
    """``slam.orbslam3.*`` set while ``systems`` does not list orbslam3: one warning naming the
    keys (accepted; nothing runs ORB-SLAM3)."""
    from .schema import OrbSlam3

    keys = changed_keys(orb, OrbSlam3(), "slam.orbslam3")
    if keys:
        warning(unused_line(keys, "systems does not list orbslam3"))


def warn_methods_untrained(grid: Mapping[str, Any]) -> None:
    """``grid.depth_sweep`` or ``grid.adabn_methods`` set (not their defaults) to methods that
    ``grid.methods`` does not train: one warning per key naming them (accepted; no depth is
    swept, no AdaBN export is made for them)."""
    from .schema import Grid

    methods = [str(m) for m in grid.get("methods") or []]
    for key in changed_keys(grid, Grid(), "grid"):
        name = key.removeprefix("grid.")
        if name not in ("depth_sweep", "adabn_methods"):
            continue
        untrained = [str(m) for m in grid.get(name) or [] if str(m) not in methods]
        if untrained:
            condition = f"grid.methods does not list {', '.join(untrained)}"
            warning(unused_line([key], condition))


def check_orbslam3(orb: Mapping[str, Any]) -> None:
    """``systems=[...,orbslam3]``: the bindings installed, a readable vocabulary (when given)
    before any work."""
    import importlib.util

    from uss_slam.slam_eval.systems.orbslam3.config import INSTALL_HINT, check_vocabulary

    if importlib.util.find_spec("pyorbslam3") is None:
        raise UssSlamError(
            f"systems: orbslam3 needs the pyorbslam3 package ({INSTALL_HINT}); without it "
            "accepted: harness"
        )
    if orb.get("vocabulary") is not None:
        try:
            check_vocabulary(str(orb["vocabulary"]))
        except UssSlamError as error:
            raise UssSlamError(f"slam.orbslam3.vocabulary: {error}") from None


def check_crf(cfg: Mapping[str, Any], grid: Grid) -> None:
    """``crf_params`` (the dense CRF's, for the ``*_crf`` variants) and, when a ``*_crf``
    variant is asked for, pydensecrf installed."""
    from uss_slam.slam_eval.segmenters.crf import INSTALL_HINT, DenseCrf

    params = cfg.get("crf_params") or {}
    DenseCrf.from_config(given(params), "crf_params")
    wanted = [v for v in grid.variants if VARIANTS[v].crf]
    if wanted and importlib.util.find_spec("pydensecrf") is None:
        raise UssSlamError(f"variants: {wanted[0]} needs pydensecrf ({INSTALL_HINT})")


def check_t0(plain: dict[str, Any], synthetic: bool) -> None:
    """``grid.oracle`` resolved in ``plain`` (null = true for synthetic data, false for real);
    the oracle of real data needs labelled target training sequences (``labels/`` in each of
    ``data.real.target``; TUM has none)."""
    grid = plain["grid"]
    if grid.get("oracle") is None:
        grid["oracle"] = synthetic
    real = plain["data"].get("real") or {}
    if synthetic or not grid["oracle"] or real.get("tum") in (None, "???"):
        return  # (a missing data.real.tum is the data checks' error)
    for name in real.get("target") or []:
        labels = Path(os.path.expanduser(str(real["tum"]))) / f"{TUM_PREFIX}{name}" / "labels"
        if not labels.is_dir():
            raise UssSlamError(
                f"grid.oracle: the target oracle trains on labelled target frames, but "
                f"data.real.target sequence {name} has no labels/ ({labels}); set "
                "grid.oracle=false"
            )


def resolve_method_overrides(plain: dict[str, Any], synthetic: bool) -> None:
    """``grid.method_overrides`` resolved in ``plain``: null = the synthetic shift preset's
    tuned settings (:data:`~uss_slam.pipelines.experiments.grid.PRESET_METHOD_OVERRIDES`), none
    for real data; a mapping is used as given (``{}``: the experiment's settings for every
    method)."""
    grid = plain["grid"]
    if grid.get("method_overrides") is not None:
        return
    shift = str(plain["data"]["synthetic"].get("shift", "tum_like")) if synthetic else None
    preset = PRESET_METHOD_OVERRIDES.get(shift, {}) if shift else {}
    grid["method_overrides"] = {m: list(v) for m, v in preset.items()}


def check_override_lists(plain: Mapping[str, Any]) -> None:
    """Each list of overrides handed on to ``uss-train`` / ``uss-slam`` sets a key once (the
    second would replace the first without a word), as on their own command lines."""
    from uss_slam.core.hydra_lines import repeated_key

    methods = plain["grid"].get("method_overrides") or {}
    lists = {"init.overrides": plain["init"].get("overrides"),
             "train.overrides": plain["train"].get("overrides"),
             "slam.overrides": plain["slam"].get("overrides"),
             "slam.orbslam3.overrides": plain["slam"]["orbslam3"].get("overrides"),
             **{f"grid.method_overrides.{m}": v for m, v in methods.items()}}  # fmt: skip
    for key, items in lists.items():
        found = repeated_key(list(items)) if isinstance(items, list) else None
        if found is not None:
            raise UssSlamError(
                f"{key}: {found[0]} is given twice ({found[1]} and {found[2]}); expected each "
                "key once"
            )


def check_counts(plain: Mapping[str, Any], synthetic: bool) -> None:
    """Synthetic evaluation sequences long enough for ``segeval.stride`` (each count's own
    range is the schema's)."""
    seg = plain.get("segeval") or {}
    if synthetic:
        syn = plain["data"]["synthetic"]
        stride = int(seg.get("stride", 5))
        if int(syn["eval_frames"]) < stride:
            raise UssSlamError(
                f"data.synthetic.eval_frames: {syn['eval_frames']} frames hold no frame for "
                f"segeval.stride={stride}; expected at least {stride}"
            )


def check_init(plain: Mapping[str, Any], synthetic: bool, sequences: Sequence[str]) -> Init:
    """The ``init`` section (absent = ``scratch``): its kind, and for ``pretrained`` either a
    readable ``init.path`` or (synthetic data only) the pretraining set and its trainings; the
    pretraining set's ``render_seed`` must differ from every seed of the source set and of the
    (training, validation and evaluation) sequences."""
    init = plain.get("init") or {}
    kind = str(init.get("kind", "scratch"))
    if kind == "scratch":
        return Init(kind)
    if init.get("path") is not None:
        expected = ("expected a pretrained weights file (a DeepLab-v2 Caffe init, a torchvision "
                    "ResNet state dict or a uss-train checkpoint)")  # fmt: skip
        path = input_file(Path(os.path.expanduser(str(init["path"]))), "init.path", expected)
        if not saved_by_torch(path):
            raise UssSlamError(f"init.path={path}: not a file torch.load reads (an ONNX model, "
                               f"say); {expected}")  # fmt: skip
        return Init(kind, path=path.resolve())
    if not synthetic:
        return Init(kind)  # no init: an error after the data checks (check_real_init)
    seeds = list(init["seeds"])  # each once: the schema's
    images = int(init["images"])
    size = _size("init.size", init.get("size"))
    render_seed = int(init["render_seed"])
    syn = plain["data"]["synthetic"]
    used = training_seeds(int(syn["seed"])) | {eval_seed(plain, name) for name in sequences}
    if render_seed in used:
        raise UssSlamError(
            f"init.render_seed: {render_seed} is a seed of the source set or of a sequence "
            f"({', '.join(map(str, sorted(used)))}); the pretraining set must be a collection of "
            "its own: choose another init.render_seed"
        )
    style, regime = check_init_style(init)
    experiment = str(init["experiment"])
    overrides = init.get("overrides") or []
    for item in overrides:
        if "=" not in item or item.startswith("="):
            raise UssSlamError(f"init.overrides: expected key=value overrides, got {item!r}")
    return Init(
        kind,
        seeds=tuple(int(s) for s in seeds),
        style=style,
        regime=regime,
        images=images,
        size=size,
        render_seed=render_seed,
        experiment=experiment,
        overrides=tuple(overrides),
    )


def check_init_style(init: Mapping[str, Any]) -> tuple[str, str]:
    """``init.style`` and ``init.regime``: a pretraining set with the target's lighting and
    sensor (``mixed``) cannot stand for COCO / ImageNet in a run that claims the real regime."""
    style = str(init.get("style", "source"))
    regime = str(init.get("regime", "real"))
    if style != "source" and regime == "real":
        raise UssSlamError(
            f"init.style: {style} renders half of the pretraining set in the target's lighting "
            "and sensor, which a COCO / ImageNet init has never seen; init.regime=real needs "
            "init.style=source (init.regime=legacy names the earlier tables' mixed init)"
        )
    return style, regime


def check_real_init(init: Init, synthetic: bool) -> None:
    """Real data has no synthetic pretraining set: a warm start needs ``init.path``."""
    if init.pretrains and not synthetic:
        raise UssSlamError(
            "init.path: missing; data.kind=real with init.kind=pretrained needs the pretrained "
            "weights file every training starts from (init.path=FILE, e.g. the COCO-pretrained "
            "DeepLab-v2 init), or init.kind=scratch"
        )


def check_batchnorm(plain: Mapping[str, Any], grid: Grid) -> None:
    """``grid.batchnorm``'s modes against the BatchNorm modes of the network the trainings
    build (its class's ``BATCHNORM_SUPPORTED``; the config is composed only when modes are
    asked for)."""
    asked = {m: modes for m, modes in grid.batchnorm.items() if modes}
    if not asked:
        return
    from hydra.utils import get_class

    from uss_slam.pipelines.runs import compose_config

    from .overrides import config_error_line

    overrides = [f"experiment={plain['train']['experiment']}"]
    overrides += [str(o) for o in plain["train"].get("overrides") or []]
    try:
        target = str(compose_config("train", overrides).model.net._target_)
    except Exception as error:
        line = config_error_line(error, "training")
        if line is None:
            raise
        raise UssSlamError(f"train.overrides: {line}") from None
    supported = tuple(getattr(get_class(target), "BATCHNORM_SUPPORTED", ()))
    for method, modes in asked.items():
        for mode in modes:
            if mode not in supported:
                raise UssSlamError(
                    f"grid.batchnorm.{method}: mode {mode!r} is not one of the network's "
                    f"({target.rsplit('.', 1)[-1]}); accepted: {', '.join(supported)}"
                )


def check_parallelism(plain: Mapping[str, Any], missing: Sequence[str]) -> None:
    """The launcher's ``n_jobs`` (each section's: joblib's count, an integer >= 1, or negative
    for "every CPU but |n_jobs| − 1" when that leaves at least one), before any work instead of
    inside every job (the launcher group is Hydra's, outside the schema)."""
    launcher = plain.get("launcher") or {}
    cpus = machine_threads()
    for section in ("params", "train", "slam"):
        node = launcher.get(section) or {}
        key = f"launcher.{section}.n_jobs"
        if not (isinstance(node, Mapping) and "n_jobs" in node and key not in missing):
            continue
        value = node["n_jobs"]
        usable = isinstance(value, int) and not isinstance(value, bool)
        if usable and value < 0:
            usable = cpus + 1 + value >= 1
        elif usable:
            usable = 1 <= value <= MAX_THREADS
        if not usable:
            raise UssSlamError(
                f"{key}: expected an integer in 1..{MAX_THREADS} ({THREADS_PER_CPU} per CPU), "
                f"or -1 (every CPU) down to -{cpus} (one: this machine has {cpus} CPUs), "
                f"got {value!r}"
            )


def eval_seed(cfg: Mapping[str, Any], name: str) -> int:
    """The held-out seed of synthetic evaluation sequence ``name``."""
    return int(cfg["data"]["synthetic"]["eval_seed"]) + SYNTHETIC_SEQUENCES.index(name)


def check_real_given(real: dict[str, Any]) -> None:
    """``data.kind=real``: each folder of ``data.real`` and its target sequences given (one line
    naming the first one missing), before any key whose choices depend on the data."""
    for key in ("voc", "sbd", "coco", "tum"):
        if real.get(key) in (None, "???"):
            raise UssSlamError(
                f"data.real.{key}: missing; data.kind=real needs the {key.upper()} folder "
                f"(data.real.{key}=PATH)"
            )
    if not real.get("target"):
        raise UssSlamError(
            "data.real.target: missing; data.kind=real needs a non-empty list of the TUM "
            "sequences of the target domain"
        )


def check(cfg: DictConfig) -> Experiment:
    """Everything that can be checked before any work starts (one error line each)."""
    launcher_node = cfg.get("launcher")
    missing = []
    if launcher_node is not None:
        for section in ("params", "train", "slam"):
            node = launcher_node.get(section) or {}
            missing += [f"launcher.{section}.{k}" for k in node if OmegaConf.is_missing(node, k)]
    # every key's type, range and accepted values, and no key that nothing reads
    check_schema({k: v for k, v in cfg.items() if k != "hydra"}, ExperimentsSchema)
    for line in unused_settings({k: v for k, v in cfg.items() if k != "hydra"}, ExperimentsSchema):
        warning(line)  # declared needs= in the schema: accepted, changes nothing
    check_variant_filters()  # configs/variants.yaml names filter nodes only
    plain: dict[str, Any] = OmegaConf.to_container(cfg, resolve=True)  # type: ignore[assignment]
    stages = [str(s) for s in plain["stages"]]
    synthetic = plain["data"]["kind"] == "synthetic"
    if not synthetic:  # the folders first: what the other keys' choices depend on
        check_real_given(plain["data"]["real"])
    check_t0(plain, synthetic)
    resolve_method_overrides(plain, synthetic)
    check_override_lists(plain)
    check_counts(plain, synthetic)
    accepted = SYNTHETIC_SEQUENCES if synthetic else TUM_SEQUENCES
    sequences = check_sequences(plain.get("sequences"), accepted)
    init = check_init(plain, synthetic, sequences)
    grid = expand(plain, accepted, inits=(init.seeds if init.pretrains else ()) or (None,))
    check_batchnorm(plain, grid)
    check_crf(plain, grid)
    warn_methods_untrained(plain["grid"])
    launcher = plain.get("launcher") or {}
    choose("launcher.name", launcher.get("name"), LAUNCHERS)
    check_parallelism(plain, missing)
    if "orbslam3" in grid.systems:
        check_orbslam3(plain["slam"].get("orbslam3") or {})
    else:
        warn_orbslam3_unused(plain["slam"].get("orbslam3") or {})
    if synthetic:
        syn = plain["data"]["synthetic"]
        for key in ("voc_size", "train_size", "eval_size"):
            _size(f"data.synthetic.{key}", syn[key])
        from uss_slam.pipelines.synthetic_data import SHIFT_WARDROBE

        shift = str(syn["shift"])
        outfits = syn.get("source_outfits")
        if outfits is not None and shift != "full" and outfits != SHIFT_WARDROBE[shift]:
            raise UssSlamError(
                f"data.synthetic.source_outfits: {outfits} is shift {shift}'s to choose (it "
                f"dresses the source in {SHIFT_WARDROBE[shift]}); set it to null, or use "
                "data.synthetic.shift=full"
            )
        used = training_seeds(int(syn["seed"]))
        for name in grid.sequences:
            if eval_seed(plain, name) in used:
                raise UssSlamError(
                    f"data.synthetic.eval_seed: sequence {name} would be rendered with seed "
                    f"{eval_seed(plain, name)}, a training or validation seed "
                    f"({', '.join(map(str, sorted(used)))}); choose another eval_seed"
                )
    else:
        real = plain["data"]["real"]
        check_real_init(init, synthetic)
        for key in ("voc", "sbd", "coco", "tum"):  # the folders themselves, once all are given
            input_folder(Path(os.path.expanduser(str(real[key]))), f"data.real.{key}")
    out = Path(os.path.expanduser(str(plain["out_dir"]))).resolve()
    return Experiment(
        plain,
        out,
        grid,
        tuple(s for s in STAGES if s in stages),
        synthetic,
        launcher,
        missing,
        init,
    )

"""The ``uss-slam`` configuration: one home for every default, and the checks made before any
SLAM work starts.

Defaults live in the dataclasses (:class:`~.frontend.orb.OrbConfig`,
:class:`~.tracking.config.TrackerConfig`, :class:`~.mapping.semantic_map.MapConfig`,
:class:`~.mapping.local_mapping.LocalMappingConfig`,
:class:`~.mapping.loop_closing.LoopClosingConfig`, :class:`~.scoring.evaluation.EvalConfig`); the
filters are the ``slam.filter_params`` nodes of ``configs/slam/orb_rgbd.yaml`` (``_target_`` and
parameters, built by :mod:`.filters.build`).
:func:`register_configs` turns them into Hydra structured configs in Hydra's ConfigStore
(``uss_slam_schema/slam``, ``uss_slam_schema/eval``), which ``configs/slam/orb_rgbd.yaml`` and
``configs/slam_eval.yaml`` list in their defaults: ``uss-slam --cfg job`` prints the values,
``slam.orb.n_features=500`` overrides one, and a value of the wrong type fails while the config is
composed, naming its key.

:func:`check` validates what composition cannot (allowed values, filter names and parameters,
segmenter options) and returns the typed settings of the run.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, ListConfig, OmegaConf

from uss_slam.core.errors import UssSlamError

from .filters.build import build_filters, shipped_filter_configs
from .frontend.orb import OrbConfig
from .mapping.local_mapping import LocalMappingConfig
from .mapping.loop_closing import LoopClosingConfig
from .mapping.semantic_map import MapConfig
from .scoring.evaluation import EvalConfig
from .scoring.repeats import Perturbation, perturbations
from .systems.harness import SEGMENT_SCHEDULES
from .tracking.config import REMOVED as REMOVED_TRACKER_KEYS
from .tracking.config import TrackerConfig

SCHEMA_GROUP = "uss_slam_schema"
"""ConfigStore group of the structured configs (not a choice users make)."""


def filter_defaults(nodes: dict[str, Any] | None = None) -> dict[str, dict[str, Any]]:
    """``{filter name: {parameter: default}}`` from the constructors of the filter nodes'
    ``_target_`` classes (``nodes``: the shipped ones of ``configs/slam/orb_rgbd.yaml`` when
    None); a node whose ``_target_`` cannot be imported fails naming its key."""
    nodes = shipped_filter_configs() if nodes is None else nodes
    out: dict[str, dict[str, Any]] = {}
    for name, node in nodes.items():
        cls = _import_target(node, f"slam.filter_params.{name}")
        params = inspect.signature(cls.__init__).parameters
        out[name] = {
            p.name: list(p.default) if isinstance(p.default, tuple) else p.default
            for p in params.values()
            if p.name != "self"
        }
    return out


def _import_target(node: Any, key: str) -> type:
    """The class a config node's ``_target_`` names."""
    target = node.get("_target_") if isinstance(node, dict) else None
    if not target:
        raise UssSlamError(f"{key}: expected a mapping with _target_ (the filter class)")
    module_name, _, class_name = str(target).rpartition(".")
    try:
        return getattr(__import__(module_name, fromlist=[class_name]), class_name)
    except (ImportError, AttributeError, ValueError):
        raise UssSlamError(f"{key}._target_: cannot import {target!r}") from None


@dataclass
class SlamConfig:
    """The ``slam`` group: front end, tracker, semantic map, filter parameters, threading."""

    orb: OrbConfig = field(default_factory=OrbConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    map: MapConfig = field(default_factory=MapConfig)
    filter_params: Any = field(default_factory=dict)
    """Each filter by name: ``_target_`` (its class) and its parameters (the nodes of
    ``configs/slam/orb_rgbd.yaml``); which filters run is the top-level ``filters`` list."""
    prefetch: int = 4
    """Frames loaded ahead by background threads."""
    workers: int = 2
    """Background threads (PNG decoding releases the GIL)."""
    parallel: bool = True
    """Segment and extract ORB in those threads too (overlaps tracking)."""
    local_ba: bool = True
    """Local bundle adjustment and keyframe culling after each new keyframe (ORB-SLAM2's local
    mapping, on GTSAM); false = the tracker alone, trajectories as without a back end."""
    loop_closing: bool = True
    """Loop detection, verification and essential-graph optimisation (ORB-SLAM2's loop closing)."""
    local_ba_params: LocalMappingConfig = field(default_factory=LocalMappingConfig)
    loop_closing_params: LoopClosingConfig = field(default_factory=LoopClosingConfig)
    repeats: int = 1
    """Runs per filter set: repeat 0 unperturbed, the others with a perturbed feature budget and
    RANSAC sampling; the outputs are the median run's, with the spread (:mod:`.scoring.repeats`)."""
    repeat_seed: int = 0
    """Seed of the repeats' perturbations (the same on every sequence: paired comparisons)."""
    repeat_budget: float = 0.01
    """Relative half-width of the repeats' feature-budget jitter (0.01: ``n_features`` ± 1%)."""
    reuse_labels: bool = True
    """With ``repeats`` > 1: the segmenter labels each frame once, in repeat 0, and the later
    repeats of the filter set reuse those labels (a segmenter gives the same labels for the same
    image); the run's timing figures are then repeat 0's. False: every repeat segments again."""


def _editable(cls: type) -> DictConfig:
    """The structured config of ``cls``; frozen dataclasses give read-only nodes, which Hydra
    could not override, so every node is made writable (types are still enforced)."""
    node = OmegaConf.structured(cls)

    def unlock(cfg: Any) -> None:
        if isinstance(cfg, DictConfig):
            OmegaConf.set_readonly(cfg, False)
            for key in cfg:
                unlock(cfg[key])

    unlock(node)
    return node


def register_configs() -> None:
    """Store the schema nodes in Hydra's ConfigStore (idempotent)."""
    store = ConfigStore.instance()
    store.store(group=SCHEMA_GROUP, name="slam", node=_editable(SlamConfig))
    store.store(group=SCHEMA_GROUP, name="eval", node=_editable(EvalConfig))


# ------------------------------------------------------------------------------------ checks


@dataclass
class RunPlan:
    """The checked settings of one ``uss-slam`` invocation."""

    orb: OrbConfig
    tracker: TrackerConfig
    semantic_map: MapConfig
    evaluation: EvalConfig
    filter_params: dict[str, dict[str, Any]]
    runs: list[tuple[str | None, list[str]]]
    """``(sub-folder or None, filter names)`` per SLAM run: one run, or the baseline and each
    filter set of ``compare``."""
    backend: dict[str, Any] = field(default_factory=dict)
    """The back-end keyword arguments of :class:`~.systems.harness.SlamPipeline` (``local_ba``,
    ``loop_closing`` and their parameters)."""
    repeats: list[Perturbation] = field(default_factory=list)
    """The perturbation of each repeated run (one, unperturbed, without ``slam.repeats``)."""


def run_name(filters: Sequence[str]) -> str:
    return "+".join(filters) if filters else "baseline"


def _dataclass(cls: type, section: Any, where: str) -> Any:
    values = OmegaConf.to_container(section, resolve=True) if section is not None else {}
    known = {f.name for f in fields(cls)}
    for key in values or {}:
        if key not in known:
            raise UssSlamError(f"{where}.{key}: unknown key; expected one of {', '.join(known)}")
    try:
        return cls(**(values or {}))
    except (TypeError, ValueError) as err:
        message = str(err)
        first = message.split(" ", 1)[0]
        if first in known:  # "<field> must ...": name the full key
            return _raise(f"{where}.{message}")
        return _raise(f"{where}: {message}")


def _raise(message: str) -> Any:
    raise UssSlamError(message)


def _filter_names(value: Any, key: str, known: Sequence[str]) -> list[str]:
    if isinstance(value, str):
        names = [value]
    elif isinstance(value, (list, tuple, ListConfig)):
        names = [str(n) for n in value]
    else:
        raise UssSlamError(f"{key}: expected a list of filter names, got {value!r}")
    for name in names:
        if name not in known:
            raise UssSlamError(f"{key}: unknown filter {name!r}; choose from {', '.join(known)}")
    return names


def _compare_sets(compare: Any, known: Sequence[str]) -> list[list[str]]:
    if not isinstance(compare, (list, ListConfig)) or not compare:
        raise UssSlamError(
            "compare must be a non-empty list of filter lists, e.g. "
            "compare=[[semantic],[semantic,geometry]]"
        )
    return [_filter_names(item, f"compare[{k}]", known) for k, item in enumerate(compare)]


def _check_filter_params(params: Any) -> dict[str, dict[str, Any]]:
    """Filter nodes: each a mapping with an importable ``_target_``, parameter names its
    constructor takes, values of its default's type."""
    if params is None:
        return {}
    if not isinstance(params, dict):
        raise UssSlamError(f"slam.filter_params: expected a mapping, got {params!r}")
    for name, values in params.items():
        if not isinstance(values, dict):
            raise UssSlamError(
                f"slam.filter_params.{name}: expected a mapping with _target_ and parameters, "
                f"got {values!r}"
            )
    defaults = filter_defaults(params)
    for name, values in params.items():
        key = f"slam.filter_params.{name}"
        for param, value in values.items():
            if param == "_target_":
                continue
            if param not in defaults[name]:
                raise UssSlamError(
                    f"{key}.{param}: unknown parameter; expected one of {', '.join(defaults[name])}"
                )
            default = defaults[name][param]
            problem = _type_problem(default, value)
            if problem:
                raise UssSlamError(f"{key}.{param}: {problem}")
    return params


def _type_problem(default: Any, value: Any) -> str | None:
    if isinstance(default, bool):
        return None if isinstance(value, bool) else f"expected true or false, got {value!r}"
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"expected a number, got {value!r}"
        if not math.isfinite(value):
            return f"expected a finite number, got {value!r}"
        if isinstance(default, int) and not float(value).is_integer():
            return f"expected a whole number, got {value!r}"
        return None
    if isinstance(default, list) and not isinstance(value, list):
        return f"expected a list, got {value!r}"
    return None


def _check_segmenter(section: Any) -> None:
    """The segmenter's options against its class's constructor (before it is built)."""
    target = section.get("_target_") if isinstance(section, DictConfig) else None
    if not target:
        raise UssSlamError(
            "segmenter: expected a config with _target_ (segmenter=none|labels|onnx)"
        )
    module_name, _, class_name = str(target).rpartition(".")
    try:
        module = __import__(module_name, fromlist=[class_name])
        cls = getattr(module, class_name)
    except (ImportError, AttributeError, ValueError):
        raise UssSlamError(f"segmenter._target_: cannot import {target!r}") from None
    params = inspect.signature(cls).parameters
    accepts_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    options = [k for k in section if not str(k).startswith("_")]
    for key in options:
        if key not in params and not accepts_any:
            allowed = ", ".join(params) or "none"
            raise UssSlamError(
                f"segmenter.{key}: not an option of {class_name} (options: {allowed})"
            )
    missing = [
        name
        for name, p in params.items()
        if p.default is inspect.Parameter.empty
        and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
        and name not in options
    ]
    if missing:
        raise UssSlamError(f"segmenter.{missing[0]}: required by {class_name}")


TOP_LEVEL_KEYS = ("sequence", "segmenter", "slam", "system", "eval", "filters", "segment",
                  "compare", "out_dir", "progress")  # fmt: skip
"""The top-level keys of ``configs/slam_eval.yaml`` as composed."""
SEQUENCE_KEYS = ("path", "camera", "max_diff", "start", "stride", "max_frames")
"""The keys of ``configs/sequence/default.yaml``."""


def _check_sequence(cfg: DictConfig) -> None:
    """The frame selection and association of ``sequence`` and the ``progress`` flag (plain
    keys without a typed schema): a wrong type is one line, never a traceback or a silent
    truthy string."""
    unknown = sorted(str(k) for k in cfg if str(k) not in TOP_LEVEL_KEYS)
    if unknown:  # added with +key=value: nothing would read it
        raise UssSlamError(
            f"{unknown[0]}: unknown key; uss-slam's keys are {', '.join(TOP_LEVEL_KEYS)}"
        )
    seq = cfg.get("sequence") or {}
    unknown = sorted(str(k) for k in seq if str(k) not in SEQUENCE_KEYS)
    if unknown:
        raise UssSlamError(
            f"sequence.{unknown[0]}: unknown key; expected one of {', '.join(SEQUENCE_KEYS)}"
        )
    for key, minimum, nullable in (
        ("start", 0, False),
        ("stride", 1, False),
        ("max_frames", 1, True),
    ):
        value = seq.get(key)
        if value is None and nullable:
            continue
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            null = " or null" if nullable else ""
            raise UssSlamError(
                f"sequence.{key} must be a whole number >= {minimum}{null}, got {value!r}"
            )
    max_diff = seq.get("max_diff")
    if isinstance(max_diff, bool) or not isinstance(max_diff, (int, float)) or not max_diff >= 0:
        raise UssSlamError(f"sequence.max_diff must be a number of seconds >= 0, got {max_diff!r}")
    if not isinstance(cfg.get("progress", True), bool):
        raise UssSlamError(f"progress must be true or false, got {cfg.progress!r}")


def check(cfg: DictConfig) -> RunPlan:
    """Validate everything the run will use, before any frame is read or file written."""
    for key in ("segment", "filters", "compare", "eval", "slam", "segmenter", "out_dir"):
        if key not in cfg:
            raise UssSlamError(f"{key}: missing from the config")
    segment = str(cfg.segment)
    if segment not in SEGMENT_SCHEDULES:
        raise UssSlamError(
            f"segment={segment!r}: choose every_frame (segment every frame, concurrently "
            "with ORB extraction) or keyframes (segment keyframes only)"
        )
    slam = cfg.slam
    orb = _dataclass(OrbConfig, slam.orb, "slam.orb")
    tracker = _dataclass(TrackerConfig, slam.tracker, "slam.tracker")
    semantic_map = _dataclass(MapConfig, slam.map, "slam.map")
    evaluation = _dataclass(EvalConfig, cfg.eval, "eval")
    backend = {
        "local_ba": bool(slam.local_ba),
        "loop_closing": bool(slam.loop_closing),
        "local_ba_params": _dataclass(
            LocalMappingConfig, slam.local_ba_params, "slam.local_ba_params"
        ),
        "loop_closing_params": _dataclass(
            LoopClosingConfig, slam.loop_closing_params, "slam.loop_closing_params"
        ),
    }
    for key in ("prefetch", "workers"):
        if int(slam[key]) < (0 if key == "prefetch" else 1):
            raise UssSlamError(f"slam.{key}: must be >= {0 if key == 'prefetch' else 1}")
    _check_sequence(cfg)
    repeats = _check_repeats(slam, orb.n_features)
    params = _check_filter_params(OmegaConf.to_container(slam.filter_params, resolve=True))
    known = list(params)
    if cfg.compare is None:
        runs: list[tuple[str | None, list[str]]] = [
            (None, _filter_names(cfg.filters, "filters", known))
        ]
    else:
        sets = _compare_sets(cfg.compare, known)
        runs = [("baseline", [])] + [(run_name(s), s) for s in sets]
    for _, names in runs:
        build_filters(names, params)
    build_filters(known, params)  # the parameters of unused filters are checked too
    _check_segmenter(cfg.segmenter)
    return RunPlan(orb, tracker, semantic_map, evaluation, params, runs, backend, repeats)


def removed_override(overrides: Sequence[str]) -> str | None:
    """One line for the first command-line override of a key that was removed (with what to
    use instead), or None. Composing such an override would fail with Hydra's bare "key not
    in" message, which does not say that the key once existed."""
    for override in overrides:
        key = override.lstrip("+~").split("=", 1)[0]
        section, _, name = key.rpartition(".")
        if section == "slam.tracker" and name in REMOVED_TRACKER_KEYS:
            return f"{key}: {REMOVED_TRACKER_KEYS[name]}"
    return None


def _check_repeats(slam: DictConfig, n_features: int) -> list[Perturbation]:
    """``slam.repeats``, ``slam.repeat_seed`` and ``slam.repeat_budget`` as the repeats'
    perturbations (the types are enforced by the schema while composing)."""
    count, budget = int(slam.repeats), float(slam.repeat_budget)
    if count < 1:
        raise UssSlamError(f"slam.repeats must be >= 1, got {count}")
    if not (math.isfinite(budget) and 0 <= budget < 0.5):
        raise UssSlamError(f"slam.repeat_budget must be in [0, 0.5), got {budget}")
    return perturbations(count, int(slam.repeat_seed), budget, n_features)


# ------------------------------------------------------------------------- config errors

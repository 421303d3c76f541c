"""The ``uss-slam`` configuration: one home for every default, and the checks made before any
SLAM work starts.

Defaults live in the dataclasses (:class:`~.frontend.orb.OrbConfig`,
:class:`~.tracking.config.TrackerConfig`, :class:`~.products.semantic_map.MapConfig`,
:class:`~.mapping.local_mapping.LocalMappingConfig`,
:class:`~.mapping.loop_closing.LoopClosingConfig`, :class:`~.scoring.evaluation.EvalConfig`); the
filters are the ``slam.filter_params`` nodes of ``configs/slam/orb_rgbd.yaml`` (``_target_`` and
parameters, built by :mod:`.filters.build`).
:func:`register_configs` turns them into Hydra structured configs in Hydra's ConfigStore
(``uss_slam_schema/slam``, ``uss_slam_schema/eval``), which ``configs/slam/orb_rgbd.yaml`` and
``configs/slam_eval.yaml`` list in their defaults: ``uss-slam --cfg job`` prints the values,
``slam.orb.n_features=500`` overrides one, and a value of the wrong type fails while the config is
composed, naming its key.

:func:`check` validates the composed config against :class:`SlamEvalConfig` with
:mod:`uss_slam.core.schema` (types, value ranges declared as field metadata, unknown keys: one
line ``<key>: expected ..., got ...``), the filters' and the segmenter's parameters against their
classes' annotations, then the rules across keys (filter names, a filter that needs a
segmenter), and returns the typed settings of the run.
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf

from uss_slam.core.errors import UssSlamError
from uss_slam.core.ranges import MAX_REPEATS
from uss_slam.core.schema import (
    MAX_THREADS,
    SchemaError,
    check_overrides_written,
    check_target,
    ranged,
    register,
)
from uss_slam.core.schema import check as schema_check

from .filters.build import build_filters, shipped_filter_configs
from .frontend.orb import OrbConfig
from .frontend.process import PREFETCH_MODES
from .mapping.local_mapping import LocalMappingConfig
from .mapping.loop_closing import LoopClosingConfig
from .products.semantic_map import MapConfig
from .scoring.evaluation import EvalConfig
from .scoring.repeats import Perturbation, perturbations
from .systems.harness import SEGMENT_SCHEDULES, provisional_points_refused
from .systems.late_mask import FINAL_BA
from .systems.semantic_thread import (
    CARRY_RADIUS_KEYPOINTS,
    CARRY_RADIUS_M,
    CARRY_RADIUS_MIN_INLIERS,
    CARRY_TO_KEYFRAMES,
    MASK_MARKS_PROJECTED,
    MASK_MAX_AGE_S,
    MASK_REFINES_PAST,
    MASK_REFINES_PAST_DEFAULT,
    carry_refused,
)
from .tracking.config import REMOVED as REMOVED_TRACKER_KEYS
from .tracking.config import TrackerConfig
from .variants import check_filters as check_variant_filters
from .variants import choose_variant
from .variants import read_table as read_variants

MAX_PREFETCH = 256
"""The most frames loaded ahead (about 0.5 GB of 640 × 480 frames)."""
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
    filter_params: dict[str, Any] = field(default_factory=dict)
    """Each filter by name: ``_target_`` (its class) and its parameters (the nodes of
    ``configs/slam/orb_rgbd.yaml``), checked against the class's parameter annotations; which
    filters run is the top-level ``filters`` list."""
    prefetch: int = ranged(4, min=0, max=MAX_PREFETCH)
    """Frames loaded ahead by background threads (each held in memory: a 640 × 480 frame with its
    features and labels is about 2 MB)."""
    workers: int = ranged(2, min=1, max=MAX_THREADS)
    """Background threads (PNG decoding releases the GIL); at most 4 per CPU."""
    parallel: bool = True
    """Segment and extract ORB in those threads too (overlaps tracking)."""
    reader_threads: Optional[int] = ranged(1, min=1, max=MAX_THREADS)  # noqa: UP045
    """Threads of the frame reader process (``prefetch_mode=process``) that read colour images
    and extract ORB (1: one thread fewer taking turns under that process's GIL, decided on two
    idle cores, BENCHMARKS.md); None: ``workers``. Only that process's: the prefetch threads of this
    process (the depth and labels, ``segment=every_frame``'s segmenter) stay ``workers``."""
    prefetch_mode: str = ranged("auto", choices=PREFETCH_MODES)
    """thread: read and extract ORB in this process's prefetch threads; process: in a worker
    process (its own ``workers`` threads), so that the Python work there does not take turns
    with tracking and the back end under one GIL (:mod:`.frontend.process`; the same
    trajectories); auto: process where the run has a second core to itself, thread inside a
    process pool's worker (``uss-experiments``' parallel jobs), on one CPU or when other jobs
    keep the cores busy as the run starts (:func:`.frontend.process.resolve_mode`). Used with
    ``parallel`` and ``prefetch`` > 0."""
    local_ba: bool = True
    """Local bundle adjustment and keyframe culling after each new keyframe (ORB-SLAM2's local
    mapping, on GTSAM); false = the tracker alone, trajectories as without a back end."""
    loop_closing: bool = True
    """Loop detection, verification and essential-graph optimisation (ORB-SLAM2's loop closing)."""
    local_ba_params: LocalMappingConfig = ranged(
        default_factory=LocalMappingConfig, needs="local_ba"
    )
    loop_closing_params: LoopClosingConfig = ranged(
        default_factory=LoopClosingConfig, needs="loop_closing"
    )
    provisional_points: bool = False
    """With ``segment=thread`` only: the map points of a keyframe made before its mask came are
    held back (not tracked, not optimised) until a mask clears them, and while the newest
    keyframe's are all still held, the next keyframe waits ``tracker.max_keyframe_interval``
    frames (:class:`~.systems.frame_loop.FrameLoop`). An experiment, off by default
    (docs/results/slam.md, "provisional map points, second attempt")."""
    provisional_border_px: Optional[int] = ranged(None, min=0, needs="provisional_points")  # noqa: UP045
    """With ``provisional_points``: hold back only the new points whose keypoint lies within
    this many pixels of the carried mask's dynamic region (the rest are mapped at once), and no
    keyframe wait; null = all of them, with the wait. An experiment, dropped by its
    pre-registered rule (docs/results/slam.md, "provisional map points near the carried mask")."""
    carry_to_keyframes: str = ranged("none", choices=CARRY_TO_KEYFRAMES)
    """With ``segment=thread``: the other keyframes each delivered mask is carried to (their
    poses, the mask's depth), marking bad their map points inside it: ``none`` (its own
    keyframe only), ``newer`` (also every keyframe made after it), ``since_previous`` (also
    those made since the previous mask's keyframe). An experiment, dropped by its pre-registered
    rule (docs/results/slam.md, "each delivered mask carried to the keyframes that got none")."""
    carry_velocity: bool = False
    """With ``segment=thread``: the carried mask is also drawn where each person (a connected
    labelled region) moves to, at the velocity of its 3D centroid between the last two masks
    (at most 1.5 m/s, for at most 1 s). An experiment, dropped by its pre-registered rule
    (docs/results/slam.md, "the carried mask moved with each person's velocity")."""
    carry_radius_m: Optional[float] = ranged(CARRY_RADIUS_M, gt=0)  # noqa: UP045
    """With ``segment=thread`` (the other schedules carry no mask and ignore it): a keypoint whose
    measured 3D point lies within this many metres of the carried mask's people is flagged with
    them, on a frame that keeps ``carry_radius_min_inliers`` pose inliers outside it (null =
    off). Kept with that floor by its pre-registered rule (docs/results/slam.md, "the 3D radius
    with an inlier floor"); without the floor some runs lose most frames."""
    carry_radius_keypoints: str = ranged("all", choices=CARRY_RADIUS_KEYPOINTS)
    """With ``carry_radius_m``: which keypoints near the carried people it flags: ``all``, or
    ``untracked`` (those the tracker matched to no map point: kept out of the map and of the
    keyframe rule, never taken from the pose). An experiment, dropped by its pre-registered
    rule (docs/results/slam.md, "the 3D radius on the untracked keypoints only")."""
    carry_radius_min_inliers: int = ranged(CARRY_RADIUS_MIN_INLIERS, min=0)
    """With ``carry_radius_m``: a frame that would keep fewer pose inliers outside the radius
    is not flagged by it (0 = always; without a floor walking_xyz seed 3 was lost in two of
    three repeats). docs/results/slam.md ("the 3D radius with an inlier floor")."""
    mask_max_age_s: Optional[float] = ranged(MASK_MAX_AGE_S, gt=0)  # noqa: UP045
    """With ``segment=thread`` (the other schedules ignore it): once the carried mask is older
    than this many seconds (camera time), a tracked frame that is no keyframe asks the idle
    thread for its own mask, carried from that frame's pose (null = off: only keyframes are
    segmented). Without a keyframe no mask is asked for, and a stale mask that hides the
    background where the people were can leave too few inliers to make one, or undo each
    relocalisation. An experiment, off: dropped by its pre-registered rule (docs/results/
    slam.md, "a mask for a frame when the carried one is stale")."""
    mask_refines_past: str = ranged(MASK_REFINES_PAST_DEFAULT, choices=MASK_REFINES_PAST)
    """With ``segment=thread`` (the other schedules ignore it): a mask that comes late also
    corrects the past: ``points``, local BA around its keyframe again without the map points it
    marked, and the frames tracked on them since the previous mask's keyframe refined without
    them and put back on their keyframes; ``mask``, also without the keypoints the mask carried
    back to each of those frames flags (:meth:`~.systems.frame_loop.FrameLoop.refine_past`);
    ``none``: nothing. Kept as ``mask`` by its pre-registered rule and its confirmation on
    unseen renders (docs/results/slam.md, "a late mask corrects the past")."""
    mask_marks_projected: bool = MASK_MARKS_PROJECTED
    """With ``segment=thread`` (the other schedules ignore it): a delivered mask also marks bad
    the map points first mapped since the previous mask's keyframe (keyframes no mask judged)
    that project into its dynamic region no farther than the depth measured there (the default,
    with ``mask_refines_past=mask``: docs/results/slam.md, "a late mask corrects the past")."""
    mask_refits_keyframes: bool = False
    """With ``segment=thread`` and ``mask_refines_past`` (the other schedules ignore it): a
    delivered mask is also carried back to the keyframes made since the previous mask's keyframe
    (tracked and mapped with the stale mask), their observations inside it erased, and local BA
    around its keyframe runs again with them free (:mod:`~.systems.late_mask`). An experiment,
    dropped by its pre-registered rule: it passed on the decision set and broke walking_xyz on
    the confirmation set (docs/results/slam.md, "a late mask refits the keyframes")."""
    mask_refit_min_observations: int = ranged(0, min=0)
    """With ``mask_refits_keyframes``: a keyframe that would keep fewer observations of good
    map points outside the carried mask is not refit (nothing erased, not freed); 0 = every
    keyframe is. An experiment, off by default: with a floor of 50 the refit passed on the
    decision set and lowered the thread's ATE too little on the confirmation set, both judged by
    a pre-registered rule (docs/results/slam.md, "the refit with a floor of observations")."""
    final_ba: str = ranged("none", choices=FINAL_BA)
    """With local BA: after the last frame (with ``segment=thread`` once the masks still in
    flight are delivered) one bundle adjustment of every keyframe and map point, before the
    trajectory is composed on the keyframes; an end-of-run step, not an online one. ``thread``:
    with ``segment=thread`` only; ``always``: every schedule; ``none``. An experiment, off by
    default: judged alone by a pre-registered rule and not kept, it lowered the thread's ATE
    too little (docs/results/slam.md, "the end-of-run bundle adjustment alone")."""
    semantic_nice: int = ranged(0, min=0, max=19)
    """With ``segment=thread`` and a segmenter that really runs (the wall clock): the semantic
    thread's nice value above the process's (Linux), so that tracking takes the cores first and
    the network the time left; 0 = the same priority."""
    repeats: int = ranged(1, min=1, max=MAX_REPEATS)
    """Runs per filter set: repeat 0 unperturbed, the others with a perturbed feature budget and
    RANSAC sampling; the outputs are the median run's, with the spread (:mod:`.scoring.repeats`)."""
    repeat_seed: int = 0
    """Seed of the repeats' perturbations (the same on every sequence: paired comparisons)."""
    repeat_budget: float = ranged(0.01, min=0, lt=0.5)
    """Relative half-width of the repeats' feature-budget jitter (0.01: ``n_features`` ± 1%)."""
    reuse_labels: bool = True
    """With ``repeats`` > 1: the segmenter labels each frame once, in repeat 0, and the later
    repeats of the filter set reuse those labels (a segmenter gives the same labels for the same
    image); the run's timing figures are then repeat 0's. False: every repeat segments again."""


@dataclass
class SequenceConfig:
    """The ``sequence`` group (``configs/sequence/default.yaml``): the frames of a TUM RGB-D
    sequence folder."""

    path: str = MISSING
    """The sequence folder (rgb.txt, depth.txt, groundtruth.txt, rgb/, depth/, [labels/])."""
    camera: Optional[str] = None  # noqa: UP045 (OmegaConf reads typing's Optional)
    """fr1 | fr2 | fr3 | a path to an intrinsics.yaml; null = the sequence's own, else fr3."""
    max_diff: float = ranged(0.02, gt=0)
    """Largest rgb <-> depth stamp difference, s (TUM's associate.py)."""
    start: int = ranged(0, min=0)
    """First associated frame to use."""
    stride: int = ranged(1, min=1)
    """Use every stride-th frame."""
    max_frames: Optional[int] = ranged(None, min=2)  # noqa: UP045 (a trajectory: 2 frames)
    """At most this many frames; null = all."""


@dataclass
class SlamEvalConfig:
    """The top level of ``configs/slam_eval.yaml`` as composed (``segmenter`` and ``system`` are
    checked against their ``_target_`` classes and by the system)."""

    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    segmenter: Any = None
    slam: SlamConfig = field(default_factory=SlamConfig)
    system: Any = None
    eval: EvalConfig = field(default_factory=EvalConfig)
    variant: Optional[str] = ranged(None, choices=tuple(read_variants()))  # noqa: UP045
    """A row of ``configs/variants.yaml`` (its segmenter, filters and dense CRF), or null
    (:func:`~.variants.choose_variant`)."""
    filters: Any = field(default_factory=list)
    """Filter names (a list, or one name)."""
    segment: str = ranged("every_frame", choices=SEGMENT_SCHEDULES)
    """every_frame: segment every frame, concurrently with ORB extraction; keyframes: segment
    keyframes only; thread: keyframes in a semantic thread off the tracking path, the latest
    mask carried to the frames between (:mod:`.systems.semantic_thread`)."""
    compare: Any = None
    """null, or a non-empty list of filter lists (comparison mode)."""
    out_dir: str = MISSING
    progress: bool = True


def register_configs() -> None:
    """Store the schema nodes in Hydra's ConfigStore (idempotent)."""
    register(SCHEMA_GROUP, "slam", SlamConfig)
    register(SCHEMA_GROUP, "eval", EvalConfig)
    register(SCHEMA_GROUP, "sequence", SequenceConfig)  # under a user's own sequence file


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


def _settings(cls: type, typed: Any, where: str) -> Any:
    """The settings dataclass ``cls`` of the section ``where``, whose fields
    :func:`~uss_slam.core.schema.check` checked; a rule across its fields (``min_fast`` <=
    ``ini_fast``) is a :class:`SchemaError` naming the field, here named in full."""
    values = OmegaConf.to_container(typed, resolve=True) if typed is not None else {}
    try:
        return cls(**(values or {}))
    except SchemaError as err:
        raise err.within(where) from None


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


def _check_filter_params(params: DictConfig) -> dict[str, dict[str, Any]]:
    """Filter nodes: each a mapping with a ``_target_``, its parameters checked against the
    class's parameter annotations (:func:`~uss_slam.core.schema.check_target`)."""
    for name in params:
        key = f"slam.filter_params.{name}"
        node = params[name]
        if not isinstance(node, DictConfig) or "_target_" not in node:
            raise SchemaError(key, "a mapping with _target_ (the filter class) and parameters",
                              _plain(node))  # fmt: skip
        _import_target(OmegaConf.to_container(node), key)
        check_target(node, key)
    return OmegaConf.to_container(params, resolve=True)  # type: ignore[return-value]


def _plain(node: Any) -> Any:
    return OmegaConf.to_container(node) if isinstance(node, (DictConfig, ListConfig)) else node


def _check_segmenter(section: Any) -> None:
    """The segmenter's options against its class's parameter annotations (before it is
    built), and the parameters it requires."""
    target = section.get("_target_") if isinstance(section, DictConfig) else None
    if not target:
        raise UssSlamError(
            "segmenter: expected a config with _target_ (segmenter=none|labels|onnx)"
        )
    cls = _import_target(OmegaConf.to_container(section), "segmenter")
    check_target(section, "segmenter")
    params = inspect.signature(cls).parameters
    required = [
        name
        for name, p in params.items()
        if p.default is inspect.Parameter.empty
        and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    ]
    for name in required:
        if name not in section:
            raise UssSlamError(f"segmenter.{name}: required by {cls.__name__}")


def _check_latency(section: DictConfig, segment: str) -> None:
    """A simulated segmenter latency (``segmenter.latency_s`` > 0 without ``segmenter.wait``)
    needs ``segment=thread``, the only schedule that simulates it."""
    latency = section.get("latency_s", 0) or 0
    if float(latency) > 0 and not section.get("wait", False) and segment != "thread":
        raise UssSlamError(
            f"segmenter.latency_s={float(latency):g} is simulated by segment=thread only; with "
            f"segment={segment} set segmenter.wait=true (every call then really waits)"
        )


def check(cfg: DictConfig, overrides: Sequence[str] = ()) -> RunPlan:
    """Validate everything the run will use, before any frame is read or file written: the
    config against :class:`SlamEvalConfig` (types, ranges, unknown keys), the filters' and the
    segmenter's parameters against their classes, ``configs/variants.yaml``'s filters, then
    the rules across keys. A ``variant`` sets its segmenter, filters and dense CRF in ``cfg``
    (:func:`~.variants.choose_variant`; ``overrides``: the command line's)."""
    for key in ("segment", "filters", "compare", "eval", "slam", "segmenter", "out_dir"):
        if key not in cfg:
            raise UssSlamError(f"{key}: missing from the config")
    check_overrides_written(cfg, overrides)  # typed while composing: `no` is already false
    typed = schema_check(cfg, SlamEvalConfig)
    slam = typed.slam
    orb = _settings(OrbConfig, slam.orb, "slam.orb")
    tracker = _settings(TrackerConfig, slam.tracker, "slam.tracker")
    semantic_map = _settings(MapConfig, slam.map, "slam.map")
    evaluation = _settings(EvalConfig, typed.eval, "eval")
    backend = {
        "local_ba": bool(slam.local_ba),
        "loop_closing": bool(slam.loop_closing),
        "local_ba_params": _settings(
            LocalMappingConfig, slam.local_ba_params, "slam.local_ba_params"
        ),
        "loop_closing_params": _settings(
            LoopClosingConfig, slam.loop_closing_params, "slam.loop_closing_params"
        ),
    }
    repeats = perturbations(
        int(slam.repeats), int(slam.repeat_seed), float(slam.repeat_budget), orb.n_features
    )
    params = _check_filter_params(cfg.slam.filter_params)
    known = list(params)
    check_variant_filters(read_variants(), known)  # configs/variants.yaml: known filters only
    choose_variant(cfg, overrides)
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
    _check_latency(cfg.segmenter, str(cfg.segment))
    for line in (
        provisional_points_refused(bool(cfg.slam.provisional_points), str(cfg.segment)),
        carry_refused(str(cfg.slam.carry_to_keyframes), str(cfg.segment)),
        carry_refused("velocity" if cfg.slam.carry_velocity else "none", str(cfg.segment)),
    ):
        if line is not None:
            raise UssSlamError(line)
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

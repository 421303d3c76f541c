"""The SLAM variants: one dynamic-point treatment each (which segmenter labels the frames, which
filters run, the dense CRF), in one table, ``configs/variants.yaml``, that ``uss-slam`` checks
at startup, ``uss-experiments`` runs (``variants=[...]``) and ``uss-demo`` takes its rows from.

A variant names filters by their ``slam.filter_params`` node (``configs/slam/orb_rgbd.yaml``);
a variant naming an unknown filter is one line naming the table, the variant and the filters
known. ORB-SLAM3 takes no keypoint flags: it runs the variants whose filters all find their
pixels in the frame alone (:attr:`~.filters.base.DynamicFilter.masks_input`), blanked in its
input (:func:`masks_orbslam3_input`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib.resources import files
from typing import Any

from omegaconf import OmegaConf

from uss_slam.core.errors import UssSlamError

TABLE = "variants.yaml"
"""The table's file in the ``uss_slam.configs`` tree."""

SEGMENTER_KINDS = ("none", "labels", "model")
"""A :class:`Variant`'s segmenter kinds."""

FIELDS = ("label", "segmenter", "filters", "crf")
"""The keys of a variant's entry in the table."""


@dataclass(frozen=True)
class Variant:
    """One dynamic-point treatment of a driver's SLAM runs.

    ``segmenter``: ``none``, ``labels`` (the sequence's ground-truth labels) or ``model`` (an
    exported segmenter; ``model`` names which one when a driver compares several, as the demo
    does); ``crf``: the dense CRF on the model's output (``uss-slam segmenter.crf=true``).
    """

    name: str
    label: str
    segmenter: str
    filters: tuple[str, ...] = ()
    crf: bool = False
    model: str | None = None

    def __post_init__(self) -> None:
        if self.segmenter not in SEGMENTER_KINDS:
            raise UssSlamError(
                f"variant {self.name}: segmenter {self.segmenter!r}; expected one of "
                f"{', '.join(SEGMENTER_KINDS)}"
            )
        if self.crf and self.segmenter != "model":
            raise UssSlamError(f"variant {self.name}: the dense CRF needs segmenter 'model'")


def read_table(text: str | None = None, where: str = f"configs/{TABLE}") -> dict[str, Variant]:
    """The variants by name, in the table's order (``text``: the YAML; None = the shipped
    table); an entry of the wrong shape is one line naming ``where`` and the variant."""
    if text is None:
        text = files("uss_slam.configs").joinpath(TABLE).read_text(encoding="utf-8")
    data = OmegaConf.to_container(OmegaConf.create(text), resolve=True)
    if not isinstance(data, dict) or not data:
        raise UssSlamError(f"{where}: expected a mapping of variant name -> entry")
    return {str(name): _variant(str(name), entry, where) for name, entry in data.items()}


def _variant(name: str, entry: Any, where: str) -> Variant:
    if not isinstance(entry, dict) or not {"label", "segmenter"} <= set(entry):
        raise UssSlamError(f"{where}: variant {name}: expected a mapping with label, segmenter")
    unknown = sorted(set(entry) - set(FIELDS))
    if unknown:
        raise UssSlamError(
            f"{where}: variant {name}: unknown key {unknown[0]!r}; expected {', '.join(FIELDS)}"
        )
    filters = entry.get("filters") or []
    if not isinstance(filters, list) or not all(isinstance(f, str) for f in filters):
        raise UssSlamError(f"{where}: variant {name}: filters: expected a list of filter names")
    crf = entry.get("crf", False)
    if not isinstance(crf, bool):
        raise UssSlamError(f"{where}: variant {name}: crf: expected true or false, got {crf!r}")
    try:
        return Variant(name, str(entry["label"]), str(entry["segmenter"]), tuple(filters), crf)
    except UssSlamError as err:
        raise UssSlamError(f"{where}: {err}") from None


def check_filters(
    variants: Mapping[str, Variant], known: Sequence[str], where: str = f"configs/{TABLE}"
) -> None:
    """Every filter the ``variants`` name is one of ``known`` (the filter nodes); else one line
    naming ``where``, the variant and the known filters."""
    for v in variants.values():
        for name in v.filters:
            if name not in known:
                raise UssSlamError(
                    f"{where}: variant {v.name}: unknown filter {name!r}; choose from "
                    f"{', '.join(known)} (slam.filter_params)"
                )


def variants(params: Mapping[str, Any] | None = None) -> dict[str, Variant]:
    """The shipped table, its filters checked against the filter nodes (``params`` laid over
    the shipped ones, as :func:`~.filters.build.filter_configs`)."""
    from .filters.build import filter_classes  # (the table itself is read without cv2)

    table = read_table()
    check_filters(table, list(filter_classes(params)))
    return table


def model_free(table: Mapping[str, Variant]) -> tuple[str, ...]:
    """The variants that need no trained segmenter (no filter, geometry, ground-truth masks):
    the experiments' baselines, in the table's order."""
    return tuple(name for name, v in table.items() if v.segmenter != "model")


def crf_pairs(table: Mapping[str, Variant]) -> tuple[tuple[str, str], ...]:
    """``(variant, the same with the dense CRF)`` for each CRF variant of ``table`` whose
    segmenter and filters another variant runs without the CRF, in the table's order."""
    pairs = []
    for name, v in table.items():
        if v.crf:
            off = [n for n, o in table.items()
                   if not o.crf and (o.segmenter, o.filters) == (v.segmenter, v.filters)]  # fmt: skip
            pairs += [(off[0], name)] if off else []
    return tuple(pairs)


def masks_orbslam3_input(variant: Variant, params: Mapping[str, Any] | None = None) -> bool:
    """Whether ORB-SLAM3 can run ``variant``: each of its filters finds its pixels in the frame
    alone (``masks_input``), so that they can be blanked in its input (False for a filter that
    is not a node: :func:`variants` names it)."""
    from .filters.build import filter_classes

    classes = filter_classes(params)
    return all(name in classes and classes[name].masks_input for name in variant.filters)


# ------------------------------------------------------------------- uss-slam variant=<name>

SEGMENTER_OPTIONS = {"none": "none", "labels": "labels", "model": "onnx"}
"""The ``uss-slam`` segmenter option (``configs/segmenter/<option>.yaml``) of each kind."""


def choose_variant(cfg: Any, overrides: Sequence[str] = ()) -> Any:
    """``cfg`` (the composed ``uss-slam`` config, checked against its schema and the table's
    filters against its filter nodes) with the segmenter, filters and dense CRF of its
    ``variant`` (``cfg`` as it is without one), set in place.

    ``overrides``: the command line's; a key given there (``filters``, ``segmenter``,
    ``segmenter.crf``) or set in ``cfg`` must agree with the variant, else one line naming it
    and the variant. A ``model`` variant runs the exported model that ``segmenter=onnx
    segmenter.path=FILE.onnx`` names (the only keys it leaves to the command line);
    ``compare=`` runs several filter sets, a variant one: never both.
    """
    from omegaconf import open_dict

    name = cfg.get("variant")
    if name is None:
        return cfg
    v = read_table()[str(name)]  # (a name of the table: the schema's choices, checked first)
    given = {o.lstrip("+~").split("=", 1)[0]: o.lstrip("+~") for o in overrides}
    if cfg.get("compare") is not None:
        raise UssSlamError(
            f"compare: runs several filter sets, variant={v.name} one; give one of them"
        )
    with open_dict(cfg):
        cfg.filters = _variant_filters(v, cfg.get("filters"), given.get("filters"))
        cfg.segmenter = _variant_segmenter(v, cfg.segmenter, given.get("segmenter"))
        _variant_crf(v, cfg.segmenter, given.get("segmenter.crf"))
    return cfg


def _variant_filters(v: Variant, current: Any, given: str | None) -> list[str]:
    names = [current] if isinstance(current, str) else [str(n) for n in current or []]
    if (given is not None or names) and names != list(v.filters):
        shown = given or f"filters=[{','.join(names)}]"
        raise UssSlamError(
            f"{shown}: variant={v.name} runs filters=[{','.join(v.filters)}] "
            f"(configs/{TABLE}); give one of them"
        )
    return list(v.filters)


def _option_node(option: str) -> Any:
    """The node of ``configs/segmenter/<option>.yaml``."""
    text = files("uss_slam.configs").joinpath("segmenter", f"{option}.yaml").read_text("utf-8")
    return OmegaConf.create(text)


def _variant_segmenter(v: Variant, current: Any, given: str | None) -> Any:
    """The segmenter node of ``v``: ``current`` when it is the variant's option, the option's
    node when ``current`` is the default (``none``) and not chosen on the command line."""
    option = SEGMENTER_OPTIONS[v.segmenter]
    node = _option_node(option)
    if current.get("_target_") == node["_target_"]:
        return current
    if v.segmenter == "model":
        raise UssSlamError(
            f"variant={v.name}: segments with an exported model: add segmenter=onnx "
            "segmenter.path=FILE.onnx"
        )
    if given is not None or current.get("_target_") != _option_node("none")["_target_"]:
        shown = given or f"segmenter._target_={current.get('_target_')}"
        raise UssSlamError(
            f"{shown}: variant={v.name} segments with segmenter={option} "
            f"(configs/{TABLE}); give one of them"
        )
    return node


def _variant_crf(v: Variant, segmenter: Any, given: str | None) -> None:
    """``segmenter.crf`` of ``v`` (set in ``segmenter``, a model's node)."""
    if v.segmenter != "model":
        return
    crf = bool(segmenter.get("crf", False))
    if given is not None and crf != v.crf or not v.crf and crf:
        raise UssSlamError(
            f"{given or 'segmenter.crf=true'}: variant={v.name} runs "
            f"{'with' if v.crf else 'without'} the dense CRF (configs/{TABLE}); give one of them"
        )
    segmenter.crf = v.crf

"""Filters built from their config nodes with Hydra's ``instantiate``, like every other component.

Each filter is a node of ``slam.filter_params`` (``configs/slam/orb_rgbd.yaml``): ``_target_``, its
class, and its parameters. ``filters=[semantic,geometry]`` and ``compare`` sets select nodes by
name, in the order listed; a new filter is one class and one node (``+slam.filter_params.NAME=``
with a ``_target_``), with no list in Python to extend.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from importlib.resources import files
from typing import Any

from hydra.errors import InstantiationException
from hydra.utils import get_class, instantiate
from omegaconf import OmegaConf

from uss_slam.core.errors import UssSlamError

from .base import STAGES, DynamicFilter

SHIPPED = ("slam", "orb_rgbd.yaml")
"""Where the shipped filter nodes are, in the ``uss_slam.configs`` tree."""


def shipped_filter_configs() -> dict[str, dict[str, Any]]:
    """``{name: {"_target_": class path, parameter: value}}``: the ``filter_params`` nodes of the
    shipped ``configs/slam/orb_rgbd.yaml``, for callers that build filters without composing the
    config (tests, benchmarks)."""
    text = files("uss_slam.configs").joinpath(*SHIPPED).read_text(encoding="utf-8")
    return OmegaConf.to_container(OmegaConf.create(text).filter_params, resolve=True)  # type: ignore[return-value]


def filter_configs(params: Mapping[str, Any] | None = None) -> dict[str, dict[str, Any]]:
    """The filter nodes by name: ``params`` laid over the shipped ones (a node of ``params``
    without ``_target_`` sets parameters of the shipped filter of that name; one with a
    ``_target_`` of a name not shipped adds a filter)."""
    nodes = shipped_filter_configs()
    for name, values in (params or {}).items():
        nodes[name] = {**nodes.get(name, {}), **dict(values or {})}
    return nodes


def filter_classes(params: Mapping[str, Any] | None = None) -> dict[str, type[DynamicFilter]]:
    """The class of each filter node (:func:`filter_configs`) by name, without building it; a
    ``_target_`` that cannot be imported is one line naming its key."""
    out: dict[str, type[DynamicFilter]] = {}
    for name, node in filter_configs(params).items():
        target = node.get("_target_")
        try:
            out[name] = get_class(str(target))
        except Exception:  # Hydra raises ImportError or ValueError, by version
            raise UssSlamError(
                f"slam.filter_params.{name}._target_: cannot import {target!r}"
            ) from None
    return out


def build_filters(
    names: Sequence[str], params: Mapping[str, Any] | None = None
) -> list[DynamicFilter]:
    """The filters ``names``, in that order, each instantiated from its node
    (:func:`filter_configs`); unknown names list the known ones."""
    nodes = filter_configs(params)
    out: list[DynamicFilter] = []
    for name in names:
        if name not in nodes:
            raise UssSlamError(
                f"unknown filter {name!r}; choose from {', '.join(nodes)} (filters=[...])"
            )
        if name in {f.name for f in out}:
            raise UssSlamError(f"filters: expected each filter once ({name!r} is listed twice)")
        node = nodes[name]
        if "_target_" not in node:
            raise UssSlamError(f"slam.filter_params.{name}: expected a _target_ (the filter class)")
        try:
            built = instantiate(node, _convert_="all")
        except InstantiationException as err:
            cause = err.__cause__
            if isinstance(cause, UssSlamError):
                raise cause from None
            detail = cause if isinstance(cause, TypeError) else err
            raise UssSlamError(f"filter {name!r}: bad parameters ({detail})") from None
        out.append(checked(built, name, node["_target_"]))
    return out


def checked(built: object, name: str, target: str) -> DynamicFilter:
    """``built`` when it is a filter that declares its stage; else one line naming it."""
    if not isinstance(built, DynamicFilter):
        raise UssSlamError(
            f"slam.filter_params.{name}._target_: {target} is not a DynamicFilter "
            "(uss_slam.slam_eval.filters.base)"
        )
    stage = getattr(built, "stage", None)
    if stage not in STAGES:
        raise UssSlamError(
            f"filter {name!r} ({target}) declares no stage: set its class attribute stage to "
            f"{' or '.join(map(repr, STAGES))} (before tracking / once the pose is known), "
            f"got {stage!r}"
        )
    return built

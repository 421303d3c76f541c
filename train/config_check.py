"""Config values checked against their types before anything is built: ``model.max_iters=abc``
or ``num_threads=-1`` become one line naming the key, instead of a ``TypeError`` deep inside
Lightning after the run started.

The run's own top-level keys (``seed``, ``num_threads``, ``ckpt_path``, ...) are a typed
structured config, :class:`RunSettings` (types from its annotations, ranges in its
``__post_init__``), applied to the composed config by :func:`run_settings`.

Every node with a ``_target_`` is compared with its target's parameter annotations. Only what a
config can express is judged (integers, numbers, booleans, strings, ``null``, literals and lists
of those); a parameter whose annotation admits other objects is left to the target.
"""

from __future__ import annotations

import inspect
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal, Optional, Union

from hydra.utils import get_object
from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from torch import Tensor

from uss_slam.core.errors import UssSlamError

_SCALARS = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}
_PLURALS = {int: "integers", float: "numbers", bool: "booleans", str: "strings"}
_SEQUENCES = (list, tuple, Sequence, typing.Sequence, typing.List, typing.Tuple)  # noqa: UP006


def _scalar_ok(kind: type, value: Any) -> bool:
    if kind is bool:
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    if kind is float:
        return isinstance(value, (int, float))
    return isinstance(value, kind)


def accepts(annotation: Any, value: Any) -> bool | None:
    """Whether a plain config ``value`` fits ``annotation``: True, False, or None when the
    annotation admits objects a config cannot judge (classes, callables, ``Any``)."""
    if annotation is Any or annotation is inspect.Parameter.empty:
        return None
    if annotation is type(None):
        return value is None
    if annotation in _SCALARS:
        return _scalar_ok(annotation, value)
    if annotation is Tensor:
        return False  # never a config value (optimiser lrs are annotated float | Tensor)
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Literal:
        return any(type(value) is type(a) and value == a for a in args)
    if origin is Union or origin is types.UnionType:
        verdicts = [accepts(a, value) for a in args]
        if any(v is True for v in verdicts):
            return True
        return None if any(v is None for v in verdicts) else False
    if origin in _SEQUENCES or annotation in (list, tuple):
        if not isinstance(value, (list, tuple)):
            return False
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(args) != len(value):
                return False
            items = list(zip(args, value, strict=True))
        else:
            items = [(args[0] if args else Any, v) for v in value]
        verdicts = [accepts(a, v) for a, v in items]
        if any(v is False for v in verdicts):
            return False
        return None if any(v is None for v in verdicts) else True
    if origin in (dict, Mapping, typing.Mapping) or annotation is dict:
        return isinstance(value, Mapping)
    return None


def describe(annotation: Any) -> str:
    """``int`` -> "an integer", ``int | None`` -> "an integer or null", ..."""
    if annotation is type(None):
        return "null"
    if annotation in _SCALARS:
        return _SCALARS[annotation]
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin is Union or origin is types.UnionType:
        return " or ".join(dict.fromkeys(describe(a) for a in args if a is not Tensor))
    if origin in _SEQUENCES:
        inner = [a for a in args if a is not Ellipsis]
        if not inner:
            return "a list"
        return f"a list of {_PLURALS.get(inner[0]) or describe(inner[0])}"
    return getattr(annotation, "__name__", str(annotation))


def _plain(value: Any) -> Any:
    if isinstance(value, (DictConfig, ListConfig)):
        return OmegaConf.to_container(value, resolve=True, throw_on_missing=False)
    return value


def _signature(target: str) -> tuple[inspect.Signature, dict[str, Any]] | None:
    try:
        obj = get_object(target)
        function = obj.__init__ if inspect.isclass(obj) else obj
        signature = inspect.signature(function)
        hints = typing.get_type_hints(function)
    except Exception:  # unknown target or unresolvable hints: the target reports it when built
        return None
    return signature, hints


def check_node(node: Any, key: str) -> None:
    """Check every ``_target_`` node under ``node`` (``key`` = its dotted config path).

    Raises :class:`~uss_slam.core.errors.UssSlamError` naming the first bad key: a value of the
    wrong type, or an argument the target does not take."""
    if isinstance(node, ListConfig):
        for i in range(len(node)):
            if not OmegaConf.is_missing(node, i):
                check_node(node[i], f"{key}[{i}]")
        return
    if not isinstance(node, DictConfig):
        return
    target = node.get("_target_") if "_target_" in node else None
    found = _signature(str(target)) if isinstance(target, str) else None
    if found is not None:
        signature, hints = found
        params = signature.parameters
        takes_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
        for name in node:
            name = str(name)
            if name.startswith("_"):
                continue
            where = f"{key}.{name}" if key else name
            if name not in params and not takes_any:
                raise UssSlamError(
                    f"{where}: {target} takes no argument {name!r} "
                    f"(it takes {', '.join(p for p in params if p != 'self')})"
                )
            if name not in params or OmegaConf.is_missing(node, name):
                continue
            raw = node[name]
            if isinstance(raw, DictConfig) and "_target_" in raw:
                continue  # built by its own target, checked below
            value = _plain(raw)
            if where == "trainer.precision" and value == "auto":
                continue  # resolved for the CPU or GPU when the run starts (train/speed.py)
            if accepts(hints.get(name, params[name].annotation), value) is False:
                raise UssSlamError(f"{where}: expected {describe(hints[name])}, got {value!r}")
    for name in node:
        if not str(name).startswith("_") and not OmegaConf.is_missing(node, name):
            child = node[name]
            if isinstance(child, (DictConfig, ListConfig)):
                check_node(child, f"{key}.{name}" if key else str(name))


def check_config_types(cfg: DictConfig, sections: Sequence[str]) -> None:
    """:func:`check_node` over the top-level ``sections`` of ``cfg`` that are present."""
    for section in sections:
        if section in cfg and not OmegaConf.is_missing(cfg, section):
            check_node(cfg[section], section)


MAX_SEED = 2**32 - 1
"""The largest seed numpy (and so Lightning's ``seed_everything``) accepts."""


@dataclass
class RunSettings:
    """The top level of ``uss-train``'s config (``configs/train.yaml``) besides its groups."""

    task_name: str = "train"
    run_name: str = "default"
    """Runs land in ``${paths.log_dir}/${task_name}/runs/${run_name}/<time>``."""
    tags: list[str] = field(default_factory=list)
    seed: Optional[int] = 0  # noqa: UP045 (OmegaConf reads typing's Optional)
    ckpt_path: Optional[str] = None  # noqa: UP045
    """Checkpoint to resume from: null, a ``.ckpt`` file, or ``last``."""
    num_threads: Optional[int] = None  # noqa: UP045
    """``torch.set_num_threads``: an integer >= 1, or null for torch's default."""
    optimized_metric: Optional[str] = "val/mIoU"  # noqa: UP045
    """Metric returned to Hydra sweepers."""

    def __post_init__(self) -> None:
        if self.seed is not None and not 0 <= self.seed <= MAX_SEED:
            # what numpy's and Lightning's seeding accept; Lightning raises deep inside
            raise UssSlamError(
                f"seed must be an integer in 0..{MAX_SEED} or null (no seeding), got {self.seed}"
            )
        if self.num_threads is not None and self.num_threads < 1:
            # 0 would silently mean torch's default, -1 end in torch's traceback
            raise UssSlamError(
                f"num_threads must be an integer >= 1 or null (torch's default), "
                f"got {self.num_threads}"
            )


def run_settings(cfg: DictConfig) -> RunSettings:
    """The top-level keys of ``cfg`` as :class:`RunSettings`: a value of the wrong type or out
    of range is one line naming its key."""
    values = {f.name: cfg[f.name] for f in fields(RunSettings) if f.name in cfg}
    try:
        typed = OmegaConf.merge(OmegaConf.structured(RunSettings), values)
        settings = OmegaConf.to_object(typed)
    except OmegaConfBaseException as error:
        key = getattr(error, "full_key", None) or "config"
        message = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise UssSlamError(f"{key}: {message}") from None
    assert isinstance(settings, RunSettings)
    return settings

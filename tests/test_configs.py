"""Every shipped Hydra config composes, resolves and names importable ``_target_``s.

The options are discovered from the config folders: each ``configs/*.yaml`` is a primary
config (composed after importing the module whose ``@hydra.main`` names it, if one does, as the
app would); each config folder is a group, found in the defaults of a primary config or of an
option of its parent group (``data/source`` in ``data=real``); every ``.yaml`` file in a group
folder is an option. A new option or group is
therefore covered without editing this file. Composition is fast; instantiating objects and
the ``fast_dev_run`` of every experiment are marked slow.
"""

from __future__ import annotations

import ast
import importlib
from collections.abc import Iterator
from functools import cache
from pathlib import Path
from typing import Any, NamedTuple

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import get_object, instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict

REPO = Path(__file__).resolve().parents[1]
CONFIG_DIR = REPO / "configs"
PACKAGES = ("core", "datasets", "synthetic", "models", "train", "export", "slam_eval", "pipelines")
# Hydra's own group: composed into every app, its options are Hydra's (job logging, sweeper...).
HYDRA_GROUP = "hydra"


class App(NamedTuple):
    config: str  # primary config name: configs/<config>.yaml
    module: str | None  # the module whose @hydra.main composes it (None: composed by code)


class Case(NamedTuple):
    app: App
    overrides: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.app.config}:{','.join(self.overrides) or 'defaults'}"


def _hydra_main_config(decorator: ast.expr) -> str | None:
    if isinstance(decorator, ast.Call) and ast.unparse(decorator.func) in ("hydra.main", "main"):
        for keyword in decorator.keywords:
            if keyword.arg == "config_name" and isinstance(keyword.value, ast.Constant):
                return str(keyword.value.value)
    return None


@cache
def hydra_mains() -> dict[str, str]:
    """Primary config name -> the module whose ``@hydra.main`` composes it."""
    mains = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.FunctionDef):
                    for decorator in node.decorator_list:
                        config = _hydra_main_config(decorator)
                        if config:
                            parts = path.relative_to(REPO).with_suffix("").parts
                            mains[config] = ".".join(("uss_slam", *parts))
    return mains


@cache
def hydra_apps() -> tuple[App, ...]:
    primary = sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))
    return tuple(App(config, hydra_mains().get(config)) for config in primary)


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONFIG_DIR / group).glob("*.yaml"))


def config_groups() -> list[str]:
    groups = {
        p.parent.relative_to(CONFIG_DIR).as_posix()
        for p in CONFIG_DIR.rglob("*.yaml")
        if p.parent != CONFIG_DIR
    }
    return sorted(g for g in groups if g.split("/")[0] != HYDRA_GROUP)


def _compose(app: App, overrides: list[str] | tuple[str, ...]) -> DictConfig:
    if app.module:  # what the app registers at import (structured configs)
        importlib.import_module(app.module)
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(app.config, overrides=list(overrides), return_hydra_config=True)


def _choices(app: App, overrides: list[str]) -> dict[str, Any]:
    return dict(_compose(app, overrides).hydra.runtime.choices)


@cache
def group_contexts() -> dict[str, tuple[App, tuple[str, ...]]]:
    """Each config group -> the app and the overrides under which it is in the defaults tree."""
    found: dict[str, tuple[App, tuple[str, ...]]] = {}
    groups = config_groups()
    for app in hydra_apps():
        for group in _choices(app, []):
            if group in groups:
                found.setdefault(group, (app, ()))
    changed = True
    while changed:  # nested groups: under one option of their parent group
        changed = False
        for group in groups:
            parent = group.rpartition("/")[0]
            if group in found or parent not in found or not options(group):
                continue
            app, context = found[parent]
            for option in options(parent):
                trial = [*context, f"{parent}={option}", f"{group}={options(group)[0]}"]
                try:
                    choices = _choices(app, trial)
                except Exception:  # this parent option does not hold the group
                    continue
                if choices.get(group) == options(group)[0]:
                    found[group] = (app, (*context, f"{parent}={option}"))
                    changed = True
                    break
    return found


def cases() -> list[Case]:
    """The defaults of every app, then every option of every group in its context."""
    out = [Case(app, ()) for app in hydra_apps()]
    for group, (app, context) in sorted(group_contexts().items()):
        out += [Case(app, (*context, f"{group}={option}")) for option in options(group)]
    return out


def _missing_keys(node: Any, prefix: str = "") -> Iterator[tuple[DictConfig, str, str]]:
    if isinstance(node, DictConfig):
        for key in node:
            full = f"{prefix}.{key}" if prefix else str(key)
            if OmegaConf.is_missing(node, key):
                yield node, str(key), full
            else:
                yield from _missing_keys(node._get_node(key), full)
    elif isinstance(node, ListConfig):
        for index in range(len(node)):
            yield from _missing_keys(node._get_node(index), f"{prefix}[{index}]")


def prepared(case: Case, tmp_path: Path, extra: list[str] | None = None) -> DictConfig:
    """The composed config with outputs redirected into ``tmp_path`` and mandatory values
    (``???``) filled with paths under ``tmp_path``; set as the current HydraConfig."""
    cfg = _compose(case.app, [*case.overrides, *(extra or [])])
    with open_dict(cfg):
        cfg.hydra.run.dir = str(tmp_path / "run")
        cfg.hydra.sweep.dir = str(tmp_path / "multirun")
        cfg.hydra.runtime.output_dir = str(tmp_path / "run")
        cfg.hydra.job.num = 0
        if "out_dir" in cfg:
            cfg.out_dir = str(tmp_path / "out")
        if "paths" in cfg and "root_dir" in cfg.paths:
            cfg.paths.root_dir = str(tmp_path)
        for parent, key, full in list(_missing_keys(cfg)):
            parent[key] = str(tmp_path / "mandatory" / full)
    HydraConfig().set_config(cfg)
    return cfg


def resolved(case: Case, tmp_path: Path) -> dict[str, Any]:
    """``prepared(...)`` with every interpolation resolved."""
    container = OmegaConf.to_container(prepared(case, tmp_path), resolve=True)
    assert isinstance(container, dict)
    return container


def targets(node: Any) -> Iterator[str]:
    if isinstance(node, dict):
        if isinstance(node.get("_target_"), str):
            yield node["_target_"]
        for value in node.values():
            yield from targets(value)
    elif isinstance(node, list):
        for value in node:
            yield from targets(value)


def test_every_hydra_app_has_its_primary_config() -> None:
    assert set(hydra_mains()) <= {app.config for app in hydra_apps()}
    assert {"train", "slam_eval", "export"} <= set(hydra_mains())


def test_every_config_group_is_reachable() -> None:
    """A config folder that no app composes (and so no test covers) is an error."""
    unreachable = sorted(set(config_groups()) - set(group_contexts()))
    assert not unreachable, (
        f"config groups in no defaults list: {unreachable} (list each in the defaults of the "
        "config that uses it, `- <group>: null` when it is optional)"
    )
    assert {"trainer", "logger", "callbacks", "model/net", "data/source", "segmenter"} <= set(
        group_contexts()
    )


@pytest.mark.parametrize("case", cases(), ids=str)
def test_config_composes_and_resolves(case: Case, tmp_path: Path) -> None:
    container = resolved(case, tmp_path)
    for override in case.overrides:
        group, _, option = override.partition("=")
        assert container["hydra"]["runtime"]["choices"][group] == option
    for target in targets(container):
        assert get_object(target) is not None, target


def test_train_outputs_land_in_the_redirected_folder(tmp_path: Path) -> None:
    (app,) = [a for a in hydra_apps() if a.config == "train"]
    container = resolved(Case(app, ()), tmp_path)
    assert container["paths"]["output_dir"] == str(tmp_path / "run")
    assert Path(container["paths"]["log_dir"]).parent == tmp_path


# Instantiated per option (slow: networks are built): group -> the config node it fills.
BUILT_BY_GROUP = {
    "model": "model",
    "model/net": "model.net",
    "model/method/discriminator": "model.method.discriminator",
    "model/method": "model.method",
    "callbacks": "callbacks",
    "logger": "logger",
    "trainer": "trainer",
    "segmenter": "segmenter",
}


def _instantiable(node: Any) -> list[Any]:
    """A node with a ``_target_``, or a collection of them (callbacks, loggers)."""
    if node is None:
        return []
    if "_target_" in node:
        return [node]
    return [child for child in node.values() if child is not None and "_target_" in child]


@pytest.mark.slow
@pytest.mark.parametrize(
    "case",
    [c for c in cases() if c.overrides and c.overrides[-1].split("=")[0] in BUILT_BY_GROUP],
    ids=str,
)
def test_option_instantiates(case: Case, tmp_path: Path) -> None:
    import torch

    group, _, option = case.overrides[-1].partition("=")
    path = BUILT_BY_GROUP[group]
    missing = [
        full
        for *_, full in _missing_keys(_compose(case.app, case.overrides))
        if full == path or full.startswith(f"{path}.")
    ]
    if missing:
        pytest.skip(f"{group}={option} needs values only a user can give: {missing}")
    cfg = prepared(case, tmp_path)
    node = OmegaConf.select(cfg, path)
    if group == "trainer" and node.get("precision") == "auto":  # what uss-train resolves first
        from uss_slam.train.speed import resolve_precision

        node.precision = resolve_precision("auto", node.accelerator)[0]
    if group == "trainer" and node.accelerator in ("gpu", "cuda") and not torch.cuda.is_available():
        pytest.skip(f"trainer={option} needs a GPU")
    if "model" in cfg and "net" in cfg.model and "backbone_weights" in cfg.model.net:
        cfg.model.net.backbone_weights = None  # no downloads in tests
        if "allow_random_init" in cfg.model.net:
            cfg.model.net.allow_random_init = True  # no weights files in tests
    for child in _instantiable(node):
        obj = instantiate(child)
        if child.get("_partial_"):  # built later with run-time arguments (none needed here)
            obj = obj()
        target = get_object(child._target_)
        if isinstance(target, type):
            assert isinstance(obj, target), (child._target_, type(obj))
        else:  # a factory function
            assert obj is not None, child._target_


def _tiny_data_overrides(cfg: DictConfig, data: dict[str, Path]) -> list[str]:
    """Point whatever data config the experiment composed at the tiny synthetic data."""
    if "voc" in cfg.data.source:  # data=real: the synthetic VOC tree stands in for VOC
        return [
            "data/source=[voc]",
            f"data.source.voc.root={data['voc']}",
            "data.source.voc.split=train",
            "data.source.selection.require=any",
            f"data.target.roots=[{data['target']}]",
        ]
    if cfg.data.val._target_.endswith("VOCSegmentation"):  # data=pretrain: one VOC tree
        return [f"data.source.root={data['voc']}"]
    return [
        f"data.source.root={data['voc']}",
        f"data.target.roots=[{data['target']}]",
        f"data.val.roots=[{data['val']}]",
        "data.val.stride=1",
    ]


@pytest.mark.slow
@pytest.mark.parametrize("experiment", options("experiment"))
def test_experiment_fast_dev_run(
    experiment: str,
    tmp_path: Path,
    synthetic_voc: Any,
    synthetic_sequence: Any,
) -> None:
    """Every experiment file trains one iteration and validates one batch (fast_dev_run)."""
    from uss_slam.train.train import train

    (app,) = [a for a in hydra_apps() if a.config == "train"]
    data = {
        "voc": synthetic_voc(),
        "target": synthetic_sequence(),
        "val": synthetic_sequence(frames=6, size=(160, 120), seed=1),
    }
    case = Case(app, (f"experiment={experiment}",))
    extra = [
        *_tiny_data_overrides(_compose(app, case.overrides), data),
        "+trainer.fast_dev_run=true",
        "trainer.accelerator=cpu",
        # the smallest crops every shipped discriminator depth accepts (the paper's 321 px
        # ResNet-101 step alone takes a minute on 2 cores)
        "data.source.transform.crop_size=129",
        "data.target.transform.crop_size=129",
        "model.net.backbone_weights=null",
        "model.net.allow_random_init=true",
    ]
    metrics = train(prepared(case, tmp_path, extra))
    assert metrics["iteration"] == 1
    assert "train/loss_seg_src_main" in metrics

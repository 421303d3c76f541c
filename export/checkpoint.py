"""A ``uss-train`` checkpoint -> its segmenter (``DeepLabV2`` or ``PSPNet``, eval mode, CPU).

The weights come from :func:`uss_slam.models.checkpoint.read_checkpoint`; the architecture from
the training run's ``.hydra/config.yaml`` (``model.net``) next to the checkpoint's folder, or from
a net config given explicitly (for checkpoints moved out of their run).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import file_sha256
from uss_slam.models import SEGMENTERS
from uss_slam.models.checkpoint import read_checkpoint
from uss_slam.models.deeplab import DeepLabV2
from uss_slam.models.pspnet import PSPNet


def run_config_path(ckpt_path: Path) -> Path:
    """``<run_dir>/.hydra/config.yaml`` of a checkpoint in ``<run_dir>/checkpoints/``."""
    return Path(ckpt_path).resolve().parent.parent / ".hydra" / "config.yaml"


def _load_yaml(path: Path) -> Any:
    try:
        return OmegaConf.load(path)
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        first = (str(error).strip().splitlines() or [""])[0]
        raise DataFormatError(path, f"not a readable YAML file ({first})") from error


def run_config(ckpt_path: Path) -> DictConfig | None:
    """The training run's composed config (``None`` when the checkpoint is not in its run)."""
    path = run_config_path(ckpt_path)
    if not path.is_file():
        return None
    config = _load_yaml(path)
    if not isinstance(config, DictConfig):
        raise DataFormatError(path, "expected a mapping (the run's composed Hydra config)")
    return config


def run_name(ckpt_path: Path) -> str | None:
    """The training run's ``run_name`` (``None`` without a run config or name)."""
    config = run_config(ckpt_path)
    name = config.get("run_name") if config is not None else None
    return str(name) if name else None


@dataclass(frozen=True)
class LoadedCheckpoint:
    segmenter: DeepLabV2 | PSPNet
    class_names: tuple[str, ...]
    experiment: str
    """The training run's ``run_name``, else the checkpoint's file stem."""
    sha256: str
    iteration: int | None
    net_config: dict[str, Any]


def _net_config(
    ckpt_path: Path, net_cfg: Mapping[str, Any] | str | Path | None
) -> tuple[DictConfig, str]:
    """The segmenter's Hydra config (a node with a ``_target_``) and where it was read (the
    file, or ``net_config``)."""
    if net_cfg is not None:
        if isinstance(net_cfg, (str, Path)):
            path = Path(net_cfg)
            if not path.is_file():
                raise DataFormatError(path, "net config file not found")
            node = _load_yaml(path)
        elif isinstance(net_cfg, DictConfig):
            node = net_cfg
        else:
            node = OmegaConf.create(dict(net_cfg))
        if not isinstance(node, DictConfig) or "_target_" not in node:
            raise UssSlamError(f"net config {net_cfg} has no _target_ (see configs/model/net/)")
        return node, str(net_cfg) if isinstance(net_cfg, (str, Path)) else "net_config"
    run_cfg = run_config(ckpt_path)
    run_cfg_path = run_config_path(ckpt_path)
    if run_cfg is None:
        raise DataFormatError(
            run_cfg_path,
            f"no training config for {ckpt_path} (expected the run's .hydra/config.yaml next "
            "to its checkpoints/ folder); pass net_config=<yaml of configs/model/net/>",
        )
    node = OmegaConf.select(run_cfg, "model.net")
    if not isinstance(node, DictConfig) or "_target_" not in node:
        raise DataFormatError(run_cfg_path, "expected a model.net node with a _target_")
    return node, str(run_cfg_path)


def _build(node: DictConfig, source: str) -> Any:
    """The segmenter ``node`` builds, its values first checked against the network's signature
    (a run config edited by hand: ``num_classes: four``); every problem one line naming
    ``source`` and the key."""
    from uss_slam.core.schema.fields import SchemaError
    from uss_slam.core.schema.targets import check_target

    try:
        check_target(node, "model.net")
    except SchemaError as error:
        raise DataFormatError(source, str(error)) from None
    try:
        return instantiate(node)
    except Exception as error:  # a library's text: the first line, under the file's name
        cause = error.__cause__ or error
        first = (str(cause).strip().splitlines() or [type(cause).__name__])[0]
        raise DataFormatError(source, f"cannot build model.net ({first})") from error


def load_checkpoint(
    ckpt_path: str | Path, net_cfg: Mapping[str, Any] | str | Path | None = None
) -> LoadedCheckpoint:
    """Build the segmenter of a ``uss-train`` checkpoint (eval mode, CPU).

    The architecture comes from the training run's ``.hydra/config.yaml`` (``model.net``) unless
    ``net_cfg`` (a mapping or a yaml file with a ``_target_``) overrides it; weights are the
    checkpoint's ``segmenter.*`` entries, loaded strictly (no initial weights are read or
    downloaded). Every bad file raises :class:`DataFormatError` naming it.
    """
    ckpt_path = Path(ckpt_path)
    info = read_checkpoint(ckpt_path)
    node, source = _net_config(ckpt_path, net_cfg)
    node = OmegaConf.create(OmegaConf.to_container(node, resolve=True))
    # The checkpoint holds every weight: never read (or download) initial weights.
    for key in ("weights_path", "backbone_weights"):
        if key in node:
            node[key] = None
    segmenter = _build(node, source)
    if not isinstance(segmenter, SEGMENTERS):
        expected = " or ".join(c.__name__ for c in SEGMENTERS)
        raise DataFormatError(
            ckpt_path, f"net config builds {type(segmenter).__name__}, expected {expected}"
        )
    if segmenter.num_classes != info.num_classes:
        raise DataFormatError(
            ckpt_path,
            f"checkpoint has {info.num_classes} classes ({', '.join(info.class_names)}), "
            f"the net config builds {segmenter.num_classes} (num_classes)",
        )
    try:
        segmenter.load_state_dict(info.segmenter_state, strict=True)
    except RuntimeError as error:
        raise DataFormatError(
            ckpt_path, f"segmenter weights do not fit the net config: {error}".splitlines()[0]
        ) from error
    segmenter.eval()
    name = run_name(ckpt_path)
    return LoadedCheckpoint(
        segmenter=segmenter,
        class_names=info.class_names,
        experiment=name or ckpt_path.stem,
        sha256=file_sha256(ckpt_path),
        iteration=info.iteration,
        net_config=OmegaConf.to_container(node),  # type: ignore[arg-type]
    )

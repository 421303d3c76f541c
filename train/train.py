"""``uss-train``: compose the Hydra config, instantiate data / model / trainer, fit.

Examples::

    uss-train experiment=demo
    uss-train experiment=demo ckpt_path=last          # resume the newest demo run
    uss-train -m experiment=demo model.method.discriminator.n_layers=4,5,6,7

Returns the value of ``optimized_metric`` (``val/mIoU``) so Hydra sweepers can optimise it.
"""

from __future__ import annotations

import importlib
import logging
import secrets
import signal
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Optional

import hydra
import lightning as L
import torch
from hydra.errors import InstantiationException
from hydra.utils import get_class, instantiate
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.pytorch import Callback, LightningDataModule, LightningModule, Trainer
from lightning.pytorch.callbacks import LearningRateMonitor, ProgressBar
from lightning.pytorch.loggers import Logger
from lightning_utilities.core import rank_zero
from omegaconf import DictConfig, OmegaConf, open_dict

from uss_slam.core.cli import hydra_task, run_hydra_app
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import check_writable
from uss_slam.core.paths import input_file, input_roots, naming, naming_roots
from uss_slam.core.ranges import MAX_SEED
from uss_slam.core.schema import (
    MAX_THREADS,
    Range,
    SchemaError,
    check_targets,
    declare,
    ranged,
    validate,
)
from uss_slam.datasets.precheck import check_data_files
from uss_slam.models.checkpoint import CheckpointInfo, read_checkpoint
from uss_slam.train.callbacks import LogProgressBar
from uss_slam.train.checkpoint_io import AtomicCheckpointIO
from uss_slam.train.memory import check_training_memory
from uss_slam.train.method_configs import unused_method_settings
from uss_slam.train.module import AdversarialSegmentation, resume_differences
from uss_slam.train.speed import resolve_precision
from uss_slam.train.trainer_settings import build_trainer, check_trainer_settings, trainer_error

log = logging.getLogger(__name__)
PROG = "uss-train"


def _instantiate_all(group: DictConfig | None) -> list[Any]:
    """Instantiate every entry with a ``_target_`` of a callbacks / logger group."""
    if not group:
        return []
    return [instantiate(node) for node in group.values() if node and "_target_" in node]


def resolve_ckpt_path(cfg: DictConfig) -> str | None:
    """``ckpt_path``: ``null`` (fresh run), a file, or ``last`` = the newest ``last.ckpt`` of
    an earlier run of the same ``run_name`` under ``paths.log_dir``, or of this run's own
    folder (``hydra.run.dir`` given again after a run was stopped: resumed in place)."""
    value = cfg.get("ckpt_path")
    if value is None:
        return None
    if str(value) != "last":
        expected = "expected a uss-train checkpoint (.ckpt), or last"
        return str(input_file(str(value), "ckpt_path", expected))
    runs = Path(cfg.paths.log_dir) / cfg.task_name / "runs" / str(cfg.run_name)
    output_dir = Path(cfg.paths.output_dir).resolve()
    candidates = [
        p for p in runs.glob("*/checkpoints/last.ckpt") if output_dir not in p.resolve().parents
    ]
    own = output_dir / "checkpoints" / "last.ckpt"
    candidates += [own] if own.is_file() else []
    if not candidates:
        raise UssSlamError(
            f"ckpt_path=last: no checkpoints/last.ckpt in this run's folder ({output_dir}) nor "
            f"in an earlier run under {runs}"
        )
    newest = max(candidates, key=lambda p: p.stat().st_mtime)
    log.info("resuming from %s", newest)
    return str(newest)


TYPED_SECTIONS = ("data", "model", "trainer", "callbacks", "logger")
"""Config sections whose ``_target_`` nodes are checked against their targets' signatures."""

RESOLVED_LATER = {"trainer.precision": ("auto",)}
"""Values accepted besides the annotation's: resolved for the CPU or GPU when the run starts
(:func:`~uss_slam.train.speed.resolve_precision`)."""


def config_groups() -> list[str]:
    """The config groups in ``configs/train.yaml``'s defaults list (``data``, ``model``, ...,
    a group added there included): with :class:`RunSettings`' keys, the top-level keys a run's
    config may have; any other (``+unknown=1``) is refused."""
    import yaml

    import uss_slam.configs

    text = (Path(uss_slam.configs.__file__).parent / "train.yaml").read_text(encoding="utf-8")
    defaults = yaml.safe_load(text).get("defaults") or []
    return [str(k).split()[-1] for d in defaults if isinstance(d, dict) for k in d]


# Ranges of library classes a config builds, whose annotations say only ``float`` / ``int``:
# torch would refuse these values with its own text ("Invalid momentum value") once the
# optimiser is built, Lightning would take a negative logging interval without a word.
declare("torch.optim.SGD", lr=Range(min=0), momentum=Range(min=0, lt=1), dampening=Range(min=0, max=1),
        weight_decay=Range(min=0))  # fmt: skip
declare("torch.optim.Adam", lr=Range(min=0), betas=Range(min=0, lt=1, length=2),
        eps=Range(min=0), weight_decay=Range(min=0))  # fmt: skip
declare("torch.optim.AdamW", lr=Range(min=0), betas=Range(min=0, lt=1, length=2),
        eps=Range(min=0), weight_decay=Range(min=0))  # fmt: skip
declare("lightning.pytorch.Trainer", log_every_n_steps=Range(min=1),
        max_epochs=Range(min=-1), max_steps=Range(min=-1), min_epochs=Range(min=0),
        num_sanity_val_steps=Range(min=-1), accumulate_grad_batches=Range(min=1),
        check_val_every_n_epoch=Range(min=1), gradient_clip_val=Range(min=0))  # fmt: skip


@dataclass
class RunSettings:
    """The top level of ``uss-train``'s config (``configs/train.yaml``) besides its groups."""

    task_name: str = ranged("train", text=True)
    run_name: str = ranged("default", text=True)
    """Runs land in ``${paths.log_dir}/${task_name}/runs/${run_name}/<time>``."""
    tags: list[str] = ranged(default_factory=list, text=True)
    seed: Optional[int] = ranged(0, min=0, max=MAX_SEED)  # noqa: UP045 (OmegaConf reads Optional)
    """What numpy's and Lightning's seeding accept (Lightning raises deep inside); null: no
    seeding."""
    ckpt_path: Optional[str] = None  # noqa: UP045
    """Checkpoint to resume from: null, a ``.ckpt`` file, or ``last``."""
    num_threads: Optional[int] = ranged(None, min=1, max=MAX_THREADS)  # noqa: UP045
    """``torch.set_num_threads``, or null for torch's default (0 would silently mean the
    default, -1 end in torch's traceback)."""
    optimized_metric: Optional[str] = "val/mIoU"  # noqa: UP045
    """Metric returned to Hydra sweepers."""


def check_config(cfg: DictConfig) -> RunSettings:
    """The types and ranges of ``cfg`` before anything is built: the top-level keys as
    :class:`RunSettings`, every ``_target_`` node of :data:`TYPED_SECTIONS` against its
    target's parameter annotations (:mod:`uss_slam.core.schema`). A problem is one line
    ``<key>: expected ..., got ...``."""
    names = [f.name for f in fields(RunSettings)]
    groups = [g for g in config_groups() if g != "hydra"]
    for key in cfg:
        # `hydra`: the runtime node of a config composed with return_hydra_config (the API)
        if key not in names and key not in groups and key != "hydra":
            raise SchemaError(str(key), ", ".join([*names, *groups]), unknown=True)
    values = {name: cfg[name] for name in names if name in cfg}
    settings = validate(values, RunSettings)
    check_targets(cfg, TYPED_SECTIONS, opaque=(torch.Tensor,), also=RESOLVED_LATER)
    check_crops(cfg)
    return settings


def check_crops(cfg: DictConfig) -> None:
    """The training crops are one side or two (``[h, w]``), and fit the discriminators: each of
    their ``n_layers`` stride-2 convolutions halves its input, so a crop side below
    ``2 ** n_layers`` leaves them no output (a traceback once training starts). Methods without
    discriminators need :data:`~uss_slam.datasets.transforms.MIN_CROP` only (the schema's)."""
    for domain in ("source", "target"):
        crop = ((cfg.data.get(domain) or {}).get("transform") or {}).get("crop_size")
        if crop is not None and not isinstance(crop, int) and len(crop) != 2:
            raise SchemaError(
                f"data.{domain}.transform.crop_size",
                "an integer or a list of two integers [h, w]",
                OmegaConf.to_container(crop),
            )
    method = cfg.model.get("method")
    if not isinstance(method, DictConfig):
        return
    depth = (method.get("discriminator") or {}).get("n_layers")
    if not isinstance(depth, int) or isinstance(depth, bool):
        return
    target = method.get("_target_")
    if not target or not getattr(get_class(str(target)), "trains_discriminators", False):
        return
    for domain in ("source", "target"):
        crop = ((cfg.data.get(domain) or {}).get("transform") or {}).get("crop_size")
        sides = [crop] if isinstance(crop, int) else list(crop or [])
        if any(isinstance(s, int) and s < 2**depth for s in sides):
            raise SchemaError(
                f"data.{domain}.transform.crop_size",
                f"at least {2**depth} px (2 ** model.method.discriminator.n_layers = {depth})",
                OmegaConf.to_container(crop) if not isinstance(crop, int) else crop,
            )


def _output_folders(cfg: DictConfig) -> list[tuple[str, str]]:
    """``(config key, folder)`` of every folder the run writes into besides Hydra's own."""
    folders = []
    if cfg.trainer.get("default_root_dir"):
        folders.append(("trainer.default_root_dir", str(cfg.trainer.default_root_dir)))
    for section, attribute in (("callbacks", "dirpath"), ("logger", "save_dir")):
        for name, node in (cfg.get(section) or {}).items():
            if node and "_target_" in node and node.get(attribute):
                folders.append((f"{section}.{name}.{attribute}", str(node[attribute])))
    return folders


def check_no_earlier_checkpoints(cfg: DictConfig, ckpt_path: str | None) -> None:
    """A checkpoint folder holding another run's checkpoints is refused unless this run
    resumes from a checkpoint in it: two runs' best / last checkpoints would sit side by side
    (Lightning only warns), and ``ckpt_path=last`` or an export could pick the wrong one."""
    for key, folder in _output_folders(cfg):
        if not key.startswith("callbacks."):
            continue
        path = Path(folder)
        found = sorted(path.glob("*.ckpt")) if path.is_dir() else []
        resumed = ckpt_path is not None and Path(ckpt_path).resolve().parent == path.resolve()
        if found and not resumed:
            raise UssSlamError(
                f"{key}={path}: holds checkpoints of an earlier run ({found[0].name}, "
                f"{len(found)} in all); resume it with ckpt_path={path / 'last.ckpt'} or "
                "train into a new hydra.run.dir"
            )


def check_checkpoint(path: str, cfg: DictConfig) -> CheckpointInfo:
    """The ``ckpt_path`` file is a readable ``uss-train`` checkpoint with the configured
    number of classes (one error line naming the file otherwise)."""
    num_classes = cfg.model.get("net", {}).get("num_classes")
    with naming("ckpt_path", path):  # ckpt_path=<file>: not a readable checkpoint ...
        info = read_checkpoint(path, num_classes=None if num_classes is None else int(num_classes))
    if info.iteration is None:
        raise UssSlamError(
            f"ckpt_path {path}: no 'iteration' (not a uss-train checkpoint, cannot resume)"
        )
    return info


def check_architecture(model: LightningModule, info: CheckpointInfo) -> None:
    """The checkpoint's weights fit the configured networks (same names and shapes), so that
    Lightning's restore cannot fail after the run started."""
    mine = model.state_dict()
    theirs = info.state_dict
    if isinstance(model, AdversarialSegmentation):
        # What the module's own checkpoint hook keeps (e.g. no unused discriminators).
        method = info.hyper_parameters.get("method")
        theirs = model.loadable_state(theirs, method if isinstance(method, str) else None)
    for key, value in mine.items():
        if key not in theirs:
            raise UssSlamError(
                f"ckpt_path {info.path}: has no {key} (trained with another architecture than "
                "the configured model.net / model.method.discriminator?)"
            )
        if tuple(theirs[key].shape) != tuple(value.shape):
            raise UssSlamError(
                f"ckpt_path {info.path}: {key} has shape {tuple(theirs[key].shape)}, the "
                f"configured model {tuple(value.shape)} (another model.net / "
                "model.method.discriminator?)"
            )
    extra = sorted(set(theirs) - set(mine))
    if extra:
        raise UssSlamError(
            f"ckpt_path {info.path}: holds {extra[0]} that the configured model does not have "
            "(another model.net / model.method.discriminator?)"
        )


MOVED_KEYS = {
    "model.discriminator": "model.method.discriminator",
    "model.d_optimizer": "model.method.d_optimizer",
    "model.loss.lambda_adv_aux": "model.method.lambda_adv_aux",
    "model.loss.lambda_adv_main": "model.method.lambda_adv_main",
}
"""Keys of earlier versions -> where the setting is now (the adversarial methods own their
discriminators, their optimiser and their weights)."""


def check_settings(cfg: DictConfig) -> RunSettings:
    """Every check of the composed config that needs no file and no device, in ``uss-train``'s
    order (``uss-experiments`` runs the same on each training before any starts): keys of an
    earlier version, other methods' settings (dropped, with a warning), types and ranges, the
    optimisers' values."""
    check_moved_keys(cfg)
    drop_unused_method_settings(cfg)
    settings = check_config(cfg)
    check_optimizers(cfg)
    return settings


def check_moved_keys(cfg: DictConfig) -> None:
    """A key of an earlier version (``model.discriminator.n_layers=4``) is one line naming
    where the setting is now, instead of an unknown-key error listing the model's keys."""
    for old, new in MOVED_KEYS.items():
        if OmegaConf.select(cfg, old, default=None) is not None:
            raise UssSlamError(
                f"{old}: moved to {new} (the adversarial methods own their discriminators, "
                f"their optimiser and their weights); set {new} instead"
            )


def drop_unused_method_settings(cfg: DictConfig) -> None:
    """Remove from ``model.method`` the keys its method does not take but another method does
    (each logged as a warning); a key no method takes is one line naming it."""
    node = cfg.model.get("method")
    if not isinstance(node, DictConfig):
        return
    unused = unused_method_settings(node)
    with open_dict(cfg):
        for key in unused:
            del cfg.model.method[key]


def check_method_data(cfg: DictConfig) -> None:
    """What the method needs of the data, before anything is built: target frames for a
    method that adapts (``Method.adapts``), source and target crops of one size for a method
    that combines them pixel by pixel (``Method.needs_equal_crops``)."""
    node = cfg.model.get("method")
    target = node.get("_target_") if isinstance(node, DictConfig) else None
    if not isinstance(target, str):
        return
    method = get_class(target)
    name = getattr(method, "name", target)
    data_target = cfg.data.get("target")
    if getattr(method, "adapts", False) and (
        data_target is None or data_target.get("roots", None) in ([], None)
    ):
        raise UssSlamError(
            f"model/method={name} trains on target frames: data.target is empty; set "
            "data.target.roots to the target sequences (or use model/method=source_only)"
        )
    if getattr(method, "needs_equal_crops", False):
        sizes = [
            OmegaConf.select(cfg, f"data.{domain}.transform.crop_size", default=None)
            for domain in ("source", "target")
        ]
        if None not in sizes and sizes[0] != sizes[1]:
            raise UssSlamError(
                f"model/method={name} combines source and target crops pixel by pixel: "
                f"data.source.transform.crop_size ({sizes[0]}) and "
                f"data.target.transform.crop_size ({sizes[1]}) must be equal"
            )


def check_optimizers(cfg: DictConfig) -> None:
    """Build each configured optimiser on a dummy parameter: a value torch rejects
    (``model.optimizer.lr=-1``, Adam betas outside [0, 1)) is one line naming the key before
    anything is built or written, not a traceback once training started."""
    method = cfg.model.get("method")
    nodes = {"model.optimizer": cfg.model.get("optimizer")}
    if isinstance(method, DictConfig):
        nodes["model.method.d_optimizer"] = method.get("d_optimizer")
    for key, node in nodes.items():
        if not isinstance(node, DictConfig) or "_target_" not in node:
            continue
        factory = instantiate(node)
        try:
            factory(params=[torch.nn.Parameter(torch.zeros(1))])
        except ValueError as error:
            raise UssSlamError(f"{key}: {error}") from None


def check_accelerator(cfg: DictConfig) -> None:
    """``trainer.accelerator=gpu`` (``trainer=gpu``, ``trainer=ddp``) on a machine without a
    GPU, or more ``trainer.devices`` than it has, is one line before anything is built
    (Lightning's own error comes wrapped by Hydra in two lines, after the data was built)."""
    accelerator = str(cfg.trainer.get("accelerator", "auto"))
    check_precision(cfg)
    if accelerator == "mps" and not torch.backends.mps.is_available():
        raise UssSlamError(
            "trainer.accelerator=mps: no Apple GPU (MPS) on this machine; expected cpu, gpu "
            "(a CUDA device) or auto"
        )
    if accelerator in ("tpu", "hpu", "ipu"):
        raise UssSlamError(f"trainer.accelerator={accelerator}: not supported; expected cpu, gpu, "
                           "mps or auto")  # fmt: skip
    if accelerator not in ("gpu", "cuda"):
        return
    choice = _trainer_choice()
    where = f"trainer={choice}" if choice else f"trainer.accelerator={accelerator}"
    available = torch.cuda.device_count()
    mps = accelerator == "gpu" and torch.backends.mps.is_available()
    if available == 0 and not mps:
        raise UssSlamError(
            f"{where}: no CUDA device found; use trainer=cpu (or trainer=ddp_cpu for several "
            "processes on the CPU)"
        )
    devices = cfg.trainer.get("devices")
    if isinstance(devices, int) and not isinstance(devices, bool) and devices > max(available, 1):
        raise UssSlamError(
            f"trainer.devices={devices}: only {available} CUDA device(s) found; expected at most "
            f"{available} (or trainer.devices=-1 for all of them)"
        )


UNSUPPORTED_PRECISIONS = ("64", "64-true", "double", "transformer-engine")
"""Lightning precisions the data pipeline does not follow: its batches stay float32 (a
64-bit model met them with a type error in its first forward pass)."""


def check_precision(cfg: DictConfig) -> None:
    """``trainer.precision`` one the training can run with; else one line before anything
    is built."""
    precision = str(cfg.trainer.get("precision", "32-true"))
    if precision in UNSUPPORTED_PRECISIONS:
        raise UssSlamError(
            f"trainer.precision={precision}: not supported (the batches are float32); expected "
            "32-true, bf16-mixed, 16-mixed or auto"
        )


def _trainer_choice() -> str | None:
    """The ``trainer`` config group option of this run (``gpu``, ``ddp``, ...), if Hydra says."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    choice = HydraConfig.get().runtime.choices.get("trainer")
    return str(choice) if choice else None


def check_resumed_settings(model: LightningModule, info: CheckpointInfo) -> None:
    """A resumed run (``ckpt_path``) continues the checkpoint's training: a model setting that
    differs from the checkpoint's (``model.optimizer.lr``, ``model/method``,
    ``model.max_iters``, a loss weight, ...) would be ignored by the restored optimiser or end
    the run at once, so it is refused with the differing keys. Trainer, logging, callbacks,
    paths, threads and data loading may change (:mod:`uss_slam.train.module`'s
    ``resume_differences`` compares the model's ``hyper_parameters`` only)."""
    differences = resume_differences(info.hyper_parameters, dict(model.hparams))
    if differences:
        raise UssSlamError(
            f"ckpt_path {info.path}: expected the checkpoint's model settings for a resumed "
            f"run, got other values for {'; '.join(differences)} (checkpoint -> configured); "
            "drop these overrides, or start a new run (ckpt_path=null)"
        )


def build(cfg: DictConfig, key: str) -> Any:
    """``instantiate(cfg[key])``; a ``ValueError`` its constructors raise for a value out of
    range (``data.batch_size=0``, ``model.method.discriminator.n_layers=0``) becomes one line naming
    ``key`` (Hydra wraps it with the target's name and no key)."""
    try:
        return instantiate(cfg[key])
    except InstantiationException as error:
        cause: BaseException | None = error
        while isinstance(cause, InstantiationException):
            cause = cause.__cause__
        if isinstance(cause, ValueError) and not isinstance(cause, UssSlamError):
            raise UssSlamError(f"{key}: {cause}") from error
        raise


def fit(
    trainer: Trainer,
    model: LightningModule,
    datamodule: LightningDataModule,
    ckpt_path: str | None,
) -> None:
    """``trainer.fit``, with Ctrl-C raised again as :class:`KeyboardInterrupt`.

    Lightning ends a fit interrupted by Ctrl-C with its own shutdown and ``sys.exit(1)``, and
    leaves SIGINT ignored; the console script's exit code 130 and its one line
    ``uss-train: interrupted`` need the interrupt back. The checkpoints saved before it stay as
    they were (each is written whole before the next iteration runs).
    """
    handler = signal.getsignal(signal.SIGINT)
    announcer = logging.getLogger(rank_zero.log.name)  # where Lightning logs its shutdown
    announcer.addFilter(_drop_shutdown_notice)
    try:
        trainer.fit(model, datamodule=datamodule, ckpt_path=ckpt_path)
    except MisconfigurationException as error:  # Lightning's checks as fit starts
        raise trainer_error(error) from error
    except SystemExit:
        if not trainer.interrupted:
            raise
        signal.signal(signal.SIGINT, handler)
        raise KeyboardInterrupt from None
    finally:
        announcer.removeFilter(_drop_shutdown_notice)


def _drop_shutdown_notice(record: logging.LogRecord) -> bool:
    """Logging filter: drop Lightning's "Detected KeyboardInterrupt" notice (stderr then holds
    the one line every console script prints after Ctrl-C)."""
    return "Detected KeyboardInterrupt" not in str(record.msg)


def draw_seed(cfg: DictConfig) -> None:
    """``seed=null``: a seed drawn from the system's entropy for this run (logged, and recorded
    in the checkpoints' hyper-parameters), so that every ``${seed}`` of the config (the data
    streams', the selection's) is a number; a resumed run keeps the one it is given."""
    if "seed" not in cfg or cfg.seed is not None:
        return
    with open_dict(cfg):
        cfg.seed = secrets.randbelow(MAX_SEED + 1)
    log.info("seed=null: drew seed %d for this run", cfg.seed)


def train(cfg: DictConfig) -> dict[str, float]:
    """Fit the configured model; returns the final callback metrics as floats.

    Everything a user can get wrong is checked before the trainer starts (value types of the
    config, the checkpoint to resume, the output folders), so that a bad run leaves no
    checkpoints or logs behind.
    """
    draw_seed(cfg)
    settings = check_settings(cfg)
    check_accelerator(cfg)
    if settings.num_threads is not None:
        torch.set_num_threads(settings.num_threads)
    if settings.seed is not None:
        L.seed_everything(settings.seed, workers=True, verbose=False)
    data = OmegaConf.to_container(cfg.data, resolve=True, throw_on_missing=False)
    input_roots(data, "data")  # before the data module reads them
    ckpt_path = resolve_ckpt_path(cfg)
    checkpoint = check_checkpoint(ckpt_path, cfg) if ckpt_path is not None else None
    for key, folder in _output_folders(cfg):
        check_writable(Path(folder).absolute(), key, create=False)
    check_no_earlier_checkpoints(cfg, ckpt_path)

    check_method_data(cfg)
    with naming_roots(data, "data"):  # a bad file inside a data folder names its key too
        datamodule: LightningDataModule = build(cfg, "data")
        check_data_files(datamodule)  # labels and images before Lightning's first line
    model: LightningModule = build(cfg, "model")
    if checkpoint is not None:
        check_architecture(model, checkpoint)
        check_resumed_settings(model, checkpoint)
        del checkpoint  # Lightning reads the file again; do not hold two copies
    check_training_memory(model, cfg)  # before any batch: a run that cannot fit is one line
    callbacks: list[Callback] = _instantiate_all(cfg.get("callbacks"))
    if cfg.trainer.get("enable_progress_bar", True) and not any(
        isinstance(c, ProgressBar) for c in callbacks
    ):
        # Lightning's own bar would write one line per batch into a file or CI log
        callbacks.append(LogProgressBar())
    loggers: list[Logger] = _instantiate_all(cfg.get("logger"))
    if any(type(logger).__name__ == "TensorBoardLogger" for logger in loggers):
        importlib.import_module("tensorboard")  # Lightning imports it at the first log line
    if not loggers:  # `logger=none`: nothing to monitor learning rates into
        callbacks = [c for c in callbacks if not isinstance(c, LearningRateMonitor)]
    precision, reason = resolve_precision(
        cfg.trainer.get("precision"), cfg.trainer.get("accelerator", "auto")
    )
    if reason is not None:
        print(f"uss-train: {reason}", flush=True)
        with open_dict(cfg):
            cfg.trainer.precision = precision
    # checkpoints written atomically in their folder (Lightning's go through $TMPDIR)
    plugins = [AtomicCheckpointIO()]
    check_trainer_settings(cfg, callbacks)
    trainer = build_trainer(cfg, callbacks=callbacks, logger=loggers or False, plugins=plugins)

    hparams = OmegaConf.to_container(cfg, resolve=True)
    for logger in loggers:
        logger.log_hyperparams(hparams)  # type: ignore[arg-type]

    with naming_roots(data, "data"):
        fit(trainer, model, datamodule, ckpt_path)

    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    method = getattr(model, "method", None)
    if method is not None:
        metrics.update(method.summary())
    best = getattr(trainer.checkpoint_callback, "best_model_path", "")
    if trainer.is_global_zero:
        log.info("iterations: %s, best checkpoint: %s", getattr(model, "iteration", "?"), best)
        log.info("metrics: %s", {k: round(v, 4) for k, v in metrics.items()})
    return metrics


@hydra.main(version_base="1.3", config_path="../configs", config_name="train")
def app(cfg: DictConfig) -> float | None:
    """The Hydra task; returns ``cfg.optimized_metric`` for sweepers."""
    metrics = hydra_task(PROG, train, cfg)
    if metrics is None:  # a multirun job that failed: the other jobs go on
        return None
    metric = cfg.get("optimized_metric")
    return metrics.get(metric) if metric else None


def main() -> None:
    """``uss-train``: every user error is one line on stderr and exit code 1 (config
    composition, an output folder that cannot be created, the run's own checks); in a multirun
    a failed job does not stop the others, and the failed ones are listed at the end."""
    run_hydra_app(PROG, app)


if __name__ == "__main__":
    main()

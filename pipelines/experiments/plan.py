"""The jobs of each stage of ``uss-experiments``: the ``uss-train`` / ``uss-slam`` overrides of
every cell of the grid and the cache key of each job (what its result depends on)."""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import file_sha256
from uss_slam.core.paths import path_override
from uss_slam.pipelines.runs import (
    OrbSlam3,
    Segmenter,
    SlamJob,
    select_checkpoint,
    slam_defaults_key,
)
from uss_slam.pipelines.stages import TRAINING_OUTPUTS, Stage

from .data import Data, synthetic_data_spec
from .experiment import Experiment
from .grid import ORACLE, VARIANTS, AdaBNCell, Model, SlamCell, TrainCell
from .jobs import stage_of
from .keys import given, source_val_stride
from .overrides import config_error_line, hydra_value
from .tables import SOURCE_VAL

FAST_TRAIN = (
    "model.max_iters=1",
    "data.iterations_per_epoch=1",
    "data.num_workers=0",
    "trainer.num_sanity_val_steps=0",
    "++trainer.limit_val_batches=1",
)
"""``fast_dev_run``: one training iteration (a checkpoint is still written and exported)."""


FAST_FRAMES = 20
"""``fast_dev_run``: frames per SLAM run."""

ADABN_IMAGES = 48
ADABN_BATCH_SIZE = 4
"""AdaBN's BatchNorm statistics: the cumulative average over this many evenly spaced target
training frames, in batches of this size (as the trainings' precise BatchNorm does)."""

TUM_FRAMES = "uss_slam.datasets.tum.TUMFrames"


@dataclass
class Job:
    """A job of the plan: its id (= folder), its spec (what the job app reads) and the row
    fields the tables group it by."""

    id: str
    spec: dict[str, Any]
    row: dict[str, Any]
    needs: str | None = None  # the export it needs (model name)


def _portable(values: Sequence[str], out: Path) -> list[str]:
    """Overrides as they go into a cache key: ``out_dir`` written as ``$OUT`` so that a moved
    output folder keeps its cache."""
    return [v.replace(str(out), "$OUT") for v in values]


def train_overrides(exp: Experiment, data: Data, cell: TrainCell) -> tuple[list[str], list[str]]:
    """``(overrides that define the training, runtime-only overrides)``."""
    base = common_overrides(exp, data)
    oracle = oracle_overrides(data, base) if cell.method == ORACLE else []
    return [*base, *cell.overrides(), *oracle, *init_overrides(data, cell)], runtime_overrides(exp)


def runtime_overrides(exp: Experiment) -> list[str]:
    """Overrides that change how fast a training runs, not what it computes
    (``train.num_threads``): not in its cache key."""
    threads = exp.cfg["train"].get("num_threads")
    return [] if threads is None else [f"num_threads={int(threads)}"]


def init_overrides(data: Data, cell: TrainCell) -> list[str]:
    """The warm start of a training: ``model.net.weights_path`` of its init (none from
    scratch)."""
    if not data.init:
        return []
    return [f"model.net.weights_path={hydra_value(str(data.init[cell.init]))}"]


def train_key(
    exp: Experiment, data: Data, cell: TrainCell, overrides: Sequence[str]
) -> dict[str, Any]:
    """What a training's result depends on: its overrides, its data and (warm start) the
    sha256 of its init file. From scratch the key is as it was before the warm start."""
    key: dict[str, Any] = {"overrides": _portable(overrides, exp.out), "data": data.train_key}
    if data.init:
        key["init"] = data.init_keys[cell.init]
    return key


def common_overrides(exp: Experiment, data: Data) -> list[str]:
    """The overrides every training starts with (experiment, data, ``train.overrides``)."""
    cfg = exp.cfg
    base = [f"experiment={cfg['train']['experiment']}", path_override("paths.log_dir", exp.out)]
    if exp.synthetic:
        assert data.train_dir is not None
        base.append(path_override("paths.data_dir", data.train_dir))
        # the appearance shift's target folders are not the shipped data config's
        base += synthetic_data_spec(exp).train_overrides(data.train_dir)
    else:
        real = cfg["data"]["real"]
        base += [
            path_override("data.source.voc.root", str(real["voc"])),
            path_override("data.source.sbd.root", str(real["sbd"])),
            path_override("data.source.coco.root", str(real["coco"])),
            path_override("data.target.roots", list(data.target)),
        ]
    base += [str(o) for o in cfg["train"].get("overrides") or []]
    if exp.fast:
        base += FAST_TRAIN
    return base


@functools.lru_cache(maxsize=8)
def _composed_source(base: tuple[str, ...]) -> dict[str, Any]:
    """What the trainings' ``data.source`` is (the ``train`` config composed with ``base``):
    its ``transform`` and ``on_error`` (resolved) and the VOC ``split`` it reads."""
    from omegaconf import OmegaConf

    from uss_slam.pipelines.runs import compose_config

    try:
        cfg = compose_config("train", list(base))
        node = cfg.data.source
        found: dict[str, Any] = {
            k: OmegaConf.to_container(node[k], resolve=True) if k == "transform" else node[k]
            for k in ("transform", "on_error")
            if k in node
        }
    except Exception as error:  # a bad train.overrides entry: one line
        line = config_error_line(error, "training")
        if line is None:
            raise
        raise UssSlamError(f"train.overrides: {line}") from None
    split = OmegaConf.select(cfg, "data.source.split", default=None)
    found["split"] = OmegaConf.select(cfg, "data.source.voc.split", default=split)
    return found


def oracle_overrides(data: Data, base: Sequence[str]) -> list[str]:
    """T0's target oracle: ``data.source`` replaced by the *labelled* target training frames
    (every frame of ``data.target``, with the source's training transform: the same crops) and
    no precise BatchNorm callback (its source images are gone; the oracle keeps the statistics
    of its own training). Network, budget and everything else stay the trainings'."""
    source = _composed_source(tuple(base))
    node: dict[str, Any] = {"_target_": TUM_FRAMES, "roots": [str(p) for p in data.target]}
    node["labels"] = True
    node |= {k: source[k] for k in ("on_error", "transform") if k in source}
    return ["~data.source", f"+data.source={hydra_value(node)}", "++callbacks.precise_bn=null"]


def source_val_held_out(exp: Experiment, data: Data) -> bool:
    """False when the trainings' source split holds the VOC val images T0 scores in domain
    (``trainval``, as the paper's experiment reads VOC)."""
    split = _composed_source(tuple(common_overrides(exp, data)))["split"]
    return split not in ("val", "trainval")


def plan_train(exp: Experiment, data: Data) -> list[Job]:
    jobs = []
    for cell in exp.grid.trainings:
        overrides, runtime = train_overrides(exp, data, cell)
        spec = {
            "kind": "train",
            "overrides": [*overrides, *runtime],
            "key": train_key(exp, data, cell, overrides),
            "outputs": list(TRAINING_OUTPUTS),
            "checkpoint": checkpoint_policy(exp),  # which one is reported (not in the key)
        }
        jobs.append(Job(cell.id, spec, {"kind": "train", **cell.describe()}))
    return jobs


def export_stage(exp: Experiment, cell: TrainCell) -> Stage | None:
    """The export of a complete training (None while the training is not complete)."""
    train_job = stage_of(exp.out, exp.train_specs[cell.id], cell.id)
    if not train_job.complete():
        return None
    ckpt = select_checkpoint(train_job.folder, checkpoint_policy(exp))
    stat = ckpt.stat()
    # The checkpoint's name, size and time rather than its hash: a ResNet-101 checkpoint with
    # its optimiser states is ~0.5 GB, hashed 15 times at every run otherwise.
    key = {
        "checkpoint": str(ckpt.relative_to(exp.out)),
        "bytes": stat.st_size,
        "mtime_ns": stat.st_mtime_ns,
        "train": train_job.key,
    }
    return Stage(exp.out / "exports" / cell.model, key, outputs=(Path(f"{cell.model}.onnx"),))


def adabn_stage(exp: Experiment, data: Data, cell: AdaBNCell) -> Stage | None:
    """The AdaBN export of a complete training (None while it is not complete):
    its checkpoint's export key plus what the target statistics are computed on."""
    source = export_stage(exp, cell.source)
    if source is None:
        return None
    key = {
        "adabn": {
            "images": ADABN_IMAGES,
            "batch_size": ADABN_BATCH_SIZE,
            "target": _portable([str(p) for p in data.target], exp.out),
        },
        **source.key,
    }
    return Stage(exp.out / "exports" / cell.model, key, outputs=(Path(f"{cell.model}.onnx"),))


def model_stage(exp: Experiment, data: Data, cell: Model) -> Stage | None:
    """The export stage of a model (a training's or an AdaBN one)."""
    if isinstance(cell, AdaBNCell):
        return adabn_stage(exp, data, cell)
    return export_stage(exp, cell)


def images_only(exp: Experiment) -> bool:
    """True when the evaluation data are labelled images, not recordings (the synthetic
    ``appearance`` shift): segmentation is evaluated, SLAM is not run."""
    return exp.synthetic and exp.cfg["data"]["synthetic"].get("shift") == "appearance"


def checkpoint_policy(exp: Experiment) -> str:
    """The configured checkpoint policy (``train.checkpoint``, checked before any work)."""
    return str(exp.cfg["train"].get("checkpoint") or "last")


def model_path(exp: Experiment, cell: Model) -> Path:
    return exp.out / "exports" / cell.model / f"{cell.model}.onnx"


def harness_repeats(cfg: Mapping[str, Any]) -> int:
    """``slam.repeats``: harness runs per SLAM job (checked before any work: an integer >= 1)."""
    return int(cfg["slam"].get("repeats") or 1)


def slam_job(exp: Experiment, data: Data, cell: SlamCell) -> SlamJob:
    """The SLAM run of a cell: its sequence, its variant's segmenter (the cell's exported model)
    and filters, ``slam.overrides``, ORB-SLAM3 for ``system: orbslam3``."""
    variant = VARIANTS[cell.variant]
    model = model_path(exp, cell.model) if cell.model is not None else None
    orbslam3 = None
    if cell.system == "orbslam3":
        orb = exp.cfg["slam"]["orbslam3"]
        orbslam3 = OrbSlam3(
            Path(str(data.vocabulary)),
            int(orb["repeats"]),
            tuple(str(o) for o in orb.get("overrides") or []),
        )
    extra = tuple(str(o) for o in exp.cfg["slam"].get("overrides") or [])
    repeats = harness_repeats(exp.cfg)
    if cell.system == "harness" and repeats > 1:
        extra = (f"slam.repeats={repeats}", *extra)
    return SlamJob(
        data.sequences[cell.sequence],
        Segmenter.of(variant, model, given(exp.cfg.get("crf_params"))),
        variant.filters,
        extra=extra,
        orbslam3=orbslam3,
        max_frames=FAST_FRAMES if exp.fast else None,
    )


def plan_slam(exp: Experiment, data: Data, exports: Mapping[str, str]) -> list[Job]:
    """Segmentation evaluations and SLAM runs; ``exports``: model -> ONNX sha256 (complete
    exports only; a job whose model has none is planned but blocked)."""
    jobs: list[Job] = []
    labelled = {n: str(data.sequences[n]) for n in exp.grid.sequences if n in data.labelled}
    seg_cfg = exp.cfg["segeval"]
    if labelled:
        for seg in [s for s in exp.grid.segevals if not s.source_val]:
            key = {
                "model": exports.get(seg.model.model),
                "sequences": {n: data.sequence_keys[n] for n in labelled},
                "stride": int(seg_cfg["stride"]),
            }
            spec = {
                "kind": "segeval",
                "model": str(model_path(exp, seg.model)),
                "sequences": labelled,
                "stride": int(seg_cfg["stride"]),
                "threads": seg_cfg.get("threads"),
                "key": key,
            }
            if seg.crf:  # (the key of a segmentation evaluation without the CRF has no "crf")
                key["crf"] = spec["crf"] = given(exp.cfg.get("crf_params"))
            row = {"kind": "segeval", **seg.model.describe(), "crf": int(seg.crf)}
            jobs.append(Job(seg.id, spec, row, needs=seg.model.model))
    # T0's in-domain column: the model on the source validation split
    stride = source_val_stride(exp.cfg)
    for seg in exp.grid.segevals:
        if not seg.source_val:
            continue
        source_val = {"root": str(data.source_val), "split": "val", "stride": stride}
        key = {
            "model": exports.get(seg.model.model),
            "source_val": {"data": data.source_val_key, "split": "val", "stride": stride},
        }
        spec = {
            "kind": "segeval",
            "model": str(model_path(exp, seg.model)),
            "source_val": source_val,
            "threads": seg_cfg.get("threads"),
            "key": key,
        }
        row = {"kind": "segeval", **seg.model.describe(), "sequence": SOURCE_VAL, "crf": 0}
        jobs.append(Job(seg.id, spec, row, needs=seg.model.model))
    for cell in [] if images_only(exp) else exp.grid.slams:
        job = slam_job(exp, data, cell)
        overrides = job.overrides()
        model = cell.model.model if cell.model is not None else None
        key = {
            "overrides": _portable(overrides, exp.out),
            "defaults": slam_defaults_key(),
            "sequence": data.sequence_keys[cell.sequence],
            "model": exports.get(model) if model else None,
        }
        if cell.system == "orbslam3":
            key["vocabulary"] = data.vocabulary_key
        spec = {"kind": "slam", "job": job.to_json(), "key": key, "outputs": ["metrics.json"]}
        row = {
            "kind": "slam",
            "system": cell.system,
            "sequence": cell.sequence,
            "variant": cell.variant,
            **(cell.model.describe() if cell.model else {}),
            "crf": int(VARIANTS[cell.variant].crf),
        }
        jobs.append(Job(cell.id, spec, row, needs=model))
    return jobs


def existing_exports(exp: Experiment, data: Data) -> dict[str, str]:
    """Model -> sha256 of its ONNX file, for every complete export."""
    found = {}
    for cell in exp.grid.models:
        stage = model_stage(exp, data, cell)
        if stage is not None and stage.complete():
            found[cell.model] = file_sha256(model_path(exp, cell))
    return found


def blocked_jobs(
    exp: Experiment,
    jobs: Sequence[Job],
    exports: Mapping[str, str],
    export_failures: Mapping[str, str],
) -> dict[str, str]:
    """Jobs whose model has no export, and why."""
    blocked = {}
    for job in jobs:
        if job.needs is None or job.needs in exports:
            continue
        training = exp.grid.training(job.needs).id
        if job.needs in export_failures:
            blocked[job.id] = f"needs exports/{job.needs}: its export failed"
        elif stage_of(exp.out, exp.train_specs[training], training).complete():
            blocked[job.id] = f"needs exports/{job.needs}: not exported yet (the export stage)"
        else:
            blocked[job.id] = f"needs exports/{job.needs}: training {training} has no result"
    return blocked

"""One job of ``uss-experiments`` (a training, a segmentation evaluation or a SLAM run) as a Hydra
app, and the multirun that runs a list of them through a Hydra launcher.

``uss-experiments`` writes a plan (``out_dir/jobs/<stage>.json``: every job of the stage with
its kind, its inputs and the key of its cache stamp) and runs::

    python -m uss_slam.pipelines.experiments.jobs -m plan=PLAN out=OUT 'cell=ID1','ID2',... \\
        hydra/launcher=joblib hydra.launcher.n_jobs=2

so Hydra's launcher decides where the jobs run: one after another (basic), in parallel
processes (joblib) or as a SLURM job array (submitit). Each job works in ``OUT/<id>/`` (Hydra's
job directory), logs to ``OUT/logs/<id>.log`` and ends in one of two ways:

- done: ``result.json`` and then the cache stamp (so a job killed half-way is redone next time;
  a training killed half-way goes on from its ``checkpoints/last.ckpt`` when the next run has
  the same key, and says so in its result as ``resumed_from_iteration``);
- failed: ``failure.json`` with the reason (one line) and the traceback; the job returns normally,
  so a failure never stops the other jobs (a failed training starts afresh next time).

A job whose folder holds a finished result of other inputs runs in a hidden sibling folder
(``.<name>.next``) that replaces the earlier result only once the new one is written: a failed
rerun leaves the earlier result byte for byte, with ``failure.json`` beside it.

A job also runs alone (to debug one cell): the same command without ``-m`` and with one id.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig

from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import file_sha256, write_json_atomic
from uss_slam.core.library_warnings import quiet_known_warnings
from uss_slam.core.processes import die_with_parent, end_with_watched
from uss_slam.pipelines.runs import (
    RESUME_FROM,
    SlamJob,
    checkpoint_miou,
    run_slam,
    run_training,
    select_checkpoint,
)
from uss_slam.pipelines.stages import Stage, recover, staging_folder, swap_in

from .tables import SOURCE_VAL

log = logging.getLogger(__name__)

RESULT = "result.json"
FAILURE = "failure.json"


def stage_of(out: Path, spec: Mapping[str, Any], cell: str) -> Stage:
    """The cache :class:`Stage` of a job (the orchestrator and the job build the same one)."""
    return Stage(
        out / cell,
        key=spec["key"],
        outputs=(Path(RESULT), *(Path(p) for p in spec.get("outputs", ()))),
        resume_from=RESUME_FROM if spec.get("kind") == "train" else None,
    )


def reason_of(error: BaseException) -> str:
    """One line saying why a job failed: a project error's own message, else type and message."""
    text = str(error).strip().splitlines()
    first = text[0] if text else ""
    if isinstance(error, UssSlamError):
        return first or type(error).__name__
    return f"{type(error).__name__}: {first}" if first else type(error).__name__


# ------------------------------------------------------------------------------------ kinds


def run_train(folder: Path, spec: Mapping[str, Any]) -> dict[str, Any]:
    """``uss-train`` with the cell's overrides into ``folder`` (checkpoints/, .hydra/config.yaml
    as uss-train writes it, for uss-export); the checkpoint the export will take."""
    metrics = run_training(folder, spec["overrides"], resume=True)
    ckpt = select_checkpoint(folder, spec.get("checkpoint", "last"))
    val = checkpoint_miou(ckpt)
    start = metrics.pop("resumed_from_iteration", None)
    result = {
        "checkpoint": str(ckpt.relative_to(folder)),
        "val_mIoU": val if val is not None else metrics.get("val/mIoU"),
        "metrics": metrics,
        **({} if start is None else {"resumed_from_iteration": int(start)}),
    }
    if spec.get("init"):  # a pretraining: its checkpoint is the init of the trainings
        init = folder / str(spec["init"])
        tmp = init.with_name(init.name + ".tmp")
        shutil.copyfile(ckpt, tmp)
        tmp.replace(init)
        result |= {"init": init.name, "init_sha256": file_sha256(init)}
    return result


def run_segeval(folder: Path, spec: Mapping[str, Any]) -> dict[str, Any]:
    """An exported model's mIoU, per-class IoU and person-mask frame metrics (``uss-eval``'s)
    on the labelled frames of every evaluation sequence (every ``stride``-th), per sequence
    and pooled over all of them (``"all"``); with ``crf`` (parameters), after the dense CRF the
    ``*_crf`` SLAM runs apply; each sequence's confusion matrix is kept (``"confusion"``), so
    that any subset of the sequences can be pooled later. With ``source_val`` (``root``, ``split``, ``stride``) instead: on
    every ``stride``-th image of that split of a VOC tree (``"source_val"``: T0's in-domain
    column)."""
    import numpy as np

    from uss_slam.core.classes import CLASS_NAMES
    from uss_slam.core.seg_metrics import iou_report, mask_metrics
    from uss_slam.pipelines.evaluate import evaluate_frames, load_segmenter, sequence_frames

    infer, info = load_segmenter(Path(spec["model"]), spec.get("threads"), spec.get("crf"))
    dynamic = [CLASS_NAMES.index(c) for c in spec.get("dynamic_classes", ["person"])]
    if "source_val" in spec:
        source = spec["source_val"]
        sources = {SOURCE_VAL: voc_frames(Path(source["root"]), source["split"], source["stride"])}
    else:
        sources = {
            name: sequence_frames([Path(path)], int(spec["stride"]))
            for name, path in spec["sequences"].items()
        }
    n = len(CLASS_NAMES)
    pooled = np.zeros((n, n), np.int64)
    pooled_masks = []
    scores: dict[str, Any] = {}
    for name, frames in sources.items():
        result = evaluate_frames(infer, frames.frames(), CLASS_NAMES, dynamic)
        pooled += result.matrix
        pooled_masks += result.mask_counts
        scores[name] = {
            **iou_report(result.matrix, CLASS_NAMES),
            "person": mask_metrics(result.mask_counts),
            "frames": len(result.names),
            # rows: true class, columns: predicted (CLASS_NAMES' order): pools any subset
            "confusion": result.matrix.tolist(),
        }
    if "source_val" not in spec:
        scores["all"] = {
            **iou_report(pooled, CLASS_NAMES),
            "person": mask_metrics(pooled_masks),
            "frames": len(pooled_masks),
        }
    return {"model": info, "sequences": scores}


def voc_frames(root: Path, split: str, stride: int) -> Any:
    """Every ``stride``-th image of split ``split`` of a VOC tree (project classes), as a
    :class:`~uss_slam.pipelines.evaluate.FrameSource`."""
    from uss_slam.datasets.voc import VOCSegmentation
    from uss_slam.pipelines.evaluate import FrameSource, LabelledFrame

    if stride < 1:
        raise UssSlamError(f"source validation stride: expected an integer >= 1, got {stride}")
    dataset = VOCSegmentation(root, split=split)
    indices = range(0, len(dataset), stride)

    def frames() -> Any:
        for k in indices:
            sample = dataset.load(k)
            rgb = sample["image"].permute(1, 2, 0).numpy()
            yield LabelledFrame(str(sample["name"]), rgb, sample["label"].numpy())

    description = {"source": "voc", "root": str(root), "split": split, "stride": stride}
    return FrameSource(description, len(indices), frames)


def run_slam_job(folder: Path, spec: Mapping[str, Any]) -> dict[str, Any]:
    """The cell's :class:`SlamJob` (``spec["job"]``), writing its outputs into ``folder``."""
    job = SlamJob.from_json(spec["job"], f"SLAM job {folder}")
    data = run_slam(job, folder, progress=False)
    result = {
        "ate": data.get("ate"),
        "tracked_fraction": data.get("tracked_fraction"),
        "fps": data.get("fps"),
    }
    if "ate_rmse_repeats" in data:  # repeated runs (slam.repeats, ORB-SLAM3's): their spread
        result["ate_rmse_repeats"] = data["ate_rmse_repeats"]
    return result


KINDS: dict[str, Callable[[Path, Mapping[str, Any]], dict[str, Any]]] = {
    "train": run_train,
    "segeval": run_segeval,
    "slam": run_slam_job,
}


# ------------------------------------------------------------------------------------ one job


def load_plan(path: Path) -> dict[str, Any]:
    try:
        plan = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as error:
        raise UssSlamError(f"{path}: not a uss-experiments job plan ({error})") from None
    if not isinstance(plan, dict) or not isinstance(plan.get("cells"), dict):
        raise UssSlamError(f"{path}: not a uss-experiments job plan (no 'cells')")
    return plan


def run_cell(plan_path: Path, out: Path, cell: str) -> dict[str, Any]:
    """Run job ``cell`` of a plan into ``out/<cell>``; a failure is recorded, never raised
    (KeyboardInterrupt and SystemExit still stop it)."""
    plan = load_plan(plan_path)
    spec = plan["cells"].get(cell)
    if spec is None:
        raise UssSlamError(f"{plan_path}: no job {cell!r}")
    # A launcher that runs jobs in processes of its own (joblib's workers, submitit's local
    # executor) leaves them running when the multirun is killed: end this one with the process
    # that started it, and with uss-experiments (which names itself in the environment), so
    # that a job never keeps writing into a folder a rerun writes too.
    die_with_parent(os.getppid())
    end_with_watched()
    quiet_known_warnings()  # a job's process is no console script's: the launcher's filters
    stage = stage_of(out, spec, cell)
    recover(stage.folder)
    if stage.complete():
        log.info("%s: complete already, reused", cell)
        return {"status": "reused"}
    # A finished earlier result (of other inputs) is replaced only by a successful new one: the
    # job then works in a hidden sibling folder, swapped in once its result is written.
    earlier = (stage.folder / RESULT).is_file()
    work = replace(stage, folder=staging_folder(stage.folder)) if earlier else stage
    work.start()  # a training interrupted earlier (same key) is kept, and goes on
    t0 = time.perf_counter()
    try:
        result = KINDS[spec["kind"]](work.folder, spec)
    except Exception as error:
        work.abandon()  # failed, not interrupted: the next run starts it afresh
        seconds = time.perf_counter() - t0
        reason = reason_of(error)
        log.error("%s failed after %.1f s: %s", cell, seconds, reason, exc_info=True)
        stage.folder.mkdir(parents=True, exist_ok=True)
        write_json_atomic(
            stage.folder / FAILURE,
            {
                "reason": reason,
                "type": type(error).__name__,
                "seconds": seconds,
                "traceback": traceback.format_exc(),
            },
        )
        return {"status": "failed", "reason": reason}
    result["seconds"] = time.perf_counter() - t0
    write_json_atomic(work.folder / RESULT, result)
    work.finish()
    if earlier:
        swap_in(work.folder, stage.folder)
    log.info("%s: done in %.1f s", cell, result["seconds"])
    return {"status": "ok", "seconds": result["seconds"]}


@hydra.main(version_base="1.3", config_path="../../configs", config_name="experiments_job")
def main(cfg: DictConfig) -> dict[str, Any]:
    """Hydra entry point of one job (``plan``, ``out``, ``cell``)."""
    return run_cell(Path(str(cfg.plan)), Path(str(cfg.out)), str(cfg.cell))


def clear_failure(folder: Path) -> None:
    """Remove a stale failure record of a job about to be (re)launched."""
    (folder / FAILURE).unlink(missing_ok=True)


if __name__ == "__main__":
    main()

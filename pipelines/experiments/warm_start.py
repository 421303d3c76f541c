"""The warm-start protocol of ``uss-experiments`` (``init.kind=pretrained``): every training of
the grid starts from a pretrained init, the stand-in for the COCO / ImageNet file users start
from, shared by every row and seed.

Part of the data stage: either the user's file (``init.path``), or, on synthetic data, a
pretraining set rendered once into ``out_dir/data/pretrain/`` (``uss-synth voc --style
<init.style> --outfits all --near 0.3``: a photo collection that is neither the source set nor
the target renders; ``init.style=source``, the real regime, shows the source domain's lighting
and camera only, ``mixed`` half of it in the target's, the earlier tables' init) and one init per seed of ``init.seeds`` trained on it into ``out_dir/data/init/i<k>/``
(``uss-train experiment=<init.experiment> data.source.root=... seed=<k>``, a job like the
trainings, run through the launcher). An init's file is its ``last.ckpt`` copied to
``init.ckpt``, with its sha256 in the job's ``result.json``; every training's overrides name
it (``model.net.weights_path``) and its cache key holds the sha256."""

from __future__ import annotations

import json
from pathlib import Path

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import file_sha256
from uss_slam.pipelines.stages import TRAINING_OUTPUTS, Stage

from .data import Data
from .experiment import Experiment
from .jobs import FAILURE, RESULT, stage_of
from .launch import describe_plan, launch
from .overrides import hydra_value
from .plan import FAST_TRAIN, Job, _portable, runtime_overrides

PRETRAIN_SET = {"outfits": "all", "near": 0.3}
"""What every pretraining set holds (``uss-synth voc --outfits all --near 0.3``): every garment
and material family the source shows, people at walking distance in 30% of the images; its
lighting is ``init.style`` (:func:`pretrain_set`)."""


def pretrain_set(style: str) -> dict[str, object]:
    """The pretraining set's recipe for ``init.style``: ``source`` (the source domain's lighting
    and camera only: the stand-in for COCO / ImageNet) or ``mixed`` (each image in the source or
    the target style, even odds: the earlier tables' init, whose cache key this keeps)."""
    return {"lighting": style, **PRETRAIN_SET}


LIGHTING = {
    "source": "the source lighting and camera only",
    "mixed": "both lightings: half in the target's lighting and sensor",
}
"""The tables' words for each ``init.style``."""
VOC_TREE = Path("VOCdevkit") / "VOC2012"
INIT_FILE = "init.ckpt"
STAGE = "init"
"""The pretrainings' plan is ``out_dir/jobs/init.json`` (their launcher section: ``train``)."""


def pretrain_set_stage(exp: Experiment) -> Stage:
    """The pretraining set (rendered once into ``out_dir/data/pretrain/``)."""
    init = exp.init
    key = {"images": init.images, "size": init.size, "seed": init.render_seed,
           **pretrain_set(init.style)}  # fmt: skip
    outputs = (VOC_TREE / "ImageSets" / "Segmentation" / "train.txt",)
    return Stage(exp.out / "data" / "pretrain", key, outputs=outputs)


def render_pretrain_set(stage: Stage) -> None:
    from uss_slam.synthetic.output import parse_size
    from uss_slam.synthetic.voc import render_voc

    key = stage.key
    stage.start()
    render_voc(stage.folder, images=key["images"], size=parse_size(key["size"]), seed=key["seed"],
               outfits=key["outfits"], near=key["near"], lighting=key["lighting"],
               overwrite=True)  # fmt: skip
    stage.finish()


def init_jobs(exp: Experiment, pretrain: Stage) -> list[Job]:
    """One pretraining job per seed of ``init.seeds`` (id ``data/init/i<k>``), cached by the
    pretraining set's key and its overrides (experiment, seed, ``init.overrides``)."""
    init = exp.init
    root = pretrain.folder / VOC_TREE
    jobs = []
    for k in init.seeds:
        overrides = [
            f"experiment={init.experiment}",
            f"data.source.root={hydra_value(str(root))}",
            f"seed={k}",
            f"run_name=init_i{k}",
            f"paths.log_dir={hydra_value(str(exp.out))}",
            *init.overrides,
            *(FAST_TRAIN if exp.fast else ()),
        ]
        spec = {
            "kind": "train",
            "overrides": [*overrides, *runtime_overrides(exp)],
            "key": {"overrides": _portable(overrides, exp.out), "pretrain": dict(pretrain.key)},
            "outputs": [*TRAINING_OUTPUTS, INIT_FILE],
            "checkpoint": "last",
            "init": INIT_FILE,
        }
        jobs.append(Job(f"data/init/i{k}", spec, {"kind": "init", "init": k, "seed": k}))
    return jobs


def describe_init(exp: Experiment) -> str | None:
    """The pretrainings' plan (dry run), or None when no init is trained."""
    if not exp.init.pretrains:
        return None
    return describe_plan(exp, STAGE, init_jobs(exp, pretrain_set_stage(exp)), set())


def stage_init(exp: Experiment, data: Data, run: bool, dry: bool = False) -> str:
    """The pretrained init(s) into ``data.init`` / ``data.init_keys``: ``init.path``, or the
    pretraining set rendered and each init trained (``run``) or found; returns a status.
    ``dry``: what is missing is reported, not an error (its sha256 is then None)."""
    init = exp.init
    if init.path is not None:
        data.init[None] = init.path
        data.init_keys[None] = file_sha256(init.path)
        return f"pretrained init {init.path} (init.path)"
    pretrain = pretrain_set_stage(exp)
    parts = []
    if pretrain.complete():
        parts.append("pretraining set reused")
    elif dry:
        parts.append(f"pretraining set to render into {pretrain.folder}")
    elif not run:
        raise DataFormatError(
            pretrain.folder, "missing or incomplete pretraining set; run the data stage"
        )
    else:
        render_pretrain_set(pretrain)
        parts.append(f"pretraining set rendered ({init.images} images, {init.size})")
    jobs = init_jobs(exp, pretrain)
    pending = {j.id for j in jobs if not stage_of(exp.out, j.spec, j.id).complete()}
    if pending and run and not dry:
        launch(exp, STAGE, jobs, set())
    for job, k in zip(jobs, init.seeds, strict=True):
        stage = stage_of(exp.out, job.spec, job.id)
        data.init[k] = stage.folder / INIT_FILE
        data.init_keys[k] = None
        if not stage.complete():
            if dry:
                parts.append(f"pretrained init i{k}: to train")
                continue
            if not run:
                raise DataFormatError(
                    stage.folder, "missing or incomplete pretrained init; run the data stage"
                )
            failure = stage.folder / FAILURE
            reason = (
                json.loads(failure.read_text(encoding="utf-8"))["reason"]
                if failure.is_file()
                else "no result (killed, or its launcher failed)"
            )
            raise UssSlamError(
                f"pretrained init i{k} ({job.id}) failed: {reason} (log: logs/{job.id}.log); "
                "every training starts from it"
            )
        result = json.loads((stage.folder / RESULT).read_text(encoding="utf-8"))
        data.init_keys[k] = str(result["init_sha256"])
        if job.id in pending:
            parts.append(f"pretrained init i{k}: trained in {_duration(result['seconds'])}")
        else:
            parts.append(f"pretrained init i{k}: reused")
    return ", ".join(parts)


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def init_header(exp: Experiment) -> str:
    """The tables' header line on where the trainings start from."""
    init = exp.init
    if not init.pretrained:
        return "- init: from scratch (random weights; init.kind=scratch)"
    if init.path is not None:
        return f"- init: pretrained, every training from {init.path} (init.path)"
    seeds = ", ".join(f"i{k}" for k in init.seeds)
    return (
        f"- init: pretrained, every training from the init of its init seed ({seeds}): "
        f"uss-train experiment={init.experiment} on a synthetic pretraining set of "
        f"{init.images} images ({init.size}, seed {init.render_seed}, {LIGHTING[init.style]}, "
        f"every garment family; init.regime={init.regime})"
        + (f", `{' '.join(init.overrides)}`" if init.overrides else "")
    )

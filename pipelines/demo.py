"""``uss-demo``: the whole story on synthetic data (what ``make demo`` runs after installing).

Stages, each printed with its elapsed time, each reused when already complete with the same
inputs (a ``.uss-demo.json`` stamp written last, see :mod:`.stages`; ``--force`` redoes
everything; a stage that was interrupted is redone):

1. ``data``: the synthetic data set (:mod:`.synthetic_data`: source VOC tree, target training,
   validation and SLAM sequences; the SLAM sequences from :data:`DEMO_SLAM_SEED`) in ``OUT/data``.
2. ``train``: the ``--experiment`` (``demo``, or ``ci`` for a seconds-long smoke run) twice, both
   from the pretrained init that ships with the package
   (:func:`~uss_slam.pipelines.assets.demo_init_path`, ``model.net.weights_path``) with the same
   budget: source-only continued (``model/method=source_only``) and adversarial adaptation
   (AdaptSegNet), into ``OUT/train/{source_only,adapted}`` (checkpoints/, .hydra/config.yaml).
3. ``export``: the last checkpoint (the fixed budget, chosen without target labels) of each run to
   ``OUT/exports/{source_only,adapted}.onnx`` with ``uss-export``'s verification, and AdaBN:
   source-only's checkpoint with BatchNorm statistics of the unlabelled target training frames
   (as ``uss-experiments`` makes its AdaBN exports) to ``OUT/exports/adabn.onnx``.
4. ``miou``: each exported model's mIoU (and per-class IoU) on the SLAM sequence's labels
   (target domain; every ``MIOU_STRIDE``-th frame) through :class:`OnnxSegmenter`.
5. ``slam``: the SLAM harness, ``slam.repeats`` runs per row (reported by the median run, with
   the min and max), on ``OUT/data/slam/<--sequence>``: no filter; ground-truth masks; the
   source-only, AdaBN and adapted ONNX masks; adapted + geometry, into ``OUT/slam/<variant>/``
   (plus ``OUT/slam/comparison.md`` in the harness's baseline-vs-each format).
6. ``report``: one table (printed) with what its numbers say (:mod:`.demo_report`), and
   ``OUT/report.md`` with ``ate_rmse.png`` (ATE per variant), ``trajectories.png`` (every
   aligned estimate vs ground truth) and each run's own plots; ``OUT/summary.json`` holds the
   table's numbers. It ends with ``uss-eval compare`` of the three models on the sequence
   (validators, mask agreement, 20 labelled frames' intervals and verdict) in ``OUT/compare/``.

Example: ``uss-demo --out outputs/demo`` (what ``make demo`` runs); ``uss-demo --until data``
renders only the data set.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from uss_slam.core.arguments import THREADS_ARG, given_once, home_expanded, path_argument
from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.cli import exit_on_user_error
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import (
    check_output_owner,
    content_key,
    file_sha256,
    output_lock,
    write_json_atomic,
)
from uss_slam.core.paths import input_folder, need_working_folder, output_folder, path_override
from uss_slam.core.ranges import MAX_THREADS
from uss_slam.slam_eval.filters.build import filter_classes
from uss_slam.slam_eval.variants import check_filters
from uss_slam.slam_eval.variants import read_table as read_variants

from . import demo_report, synthetic_data
from .assets import demo_init_path
from .experiments.overrides import hydra_value
from .runs import (
    RESUME_FROM,
    Segmenter,
    SlamJob,
    Variant,
    run_slam,
    run_training,
    select_checkpoint,
    slam_defaults_key,
)
from .stages import TRAINING_OUTPUTS, Progress, Stage, run_stage
from .synthetic_data import DemoData

MIOU_STRIDE = 10
"""Every 10th frame of the SLAM sequence is scored for mIoU (30 of the demo's 300)."""
STAGES = ("data", "train", "export", "miou", "slam", "report")
DEMO_SLAM_SEED = 3141  # chosen before any demo run looked at it; no other data set uses it
"""Seed of the demo's SLAM sequences: renders that no choice (budget, rates, filters) saw."""
SLAM_REPEATS = 3
"""Harness runs per SLAM row (``slam.repeats``): the table gives the median run and the range."""


@dataclass(frozen=True)
class Plan:
    """What ``--experiment`` changes: the data set's size, the training experiment and the
    SLAM repeats."""

    experiment: str
    data: DemoData = field(default_factory=lambda: DemoData(slam_seed=DEMO_SLAM_SEED))
    train_overrides: tuple[str, ...] = ()
    miou_stride: int = MIOU_STRIDE
    slam_repeats: int = SLAM_REPEATS


PLANS = {
    # `make demo`'s data set: 400 VOC images, 4 x 100 target training frames, 100 validation
    # frames, 2 x 300 SLAM frames at 640x480.
    "demo": Plan("demo"),
    # Seconds-long smoke run for the tests: tiny data, 4 training iterations, 2 SLAM repeats.
    "ci": Plan(
        "ci",
        data=DemoData(
            voc_images=8,
            train_frames=4,
            val_frames=4,
            train_size=(160, 120),
            slam_frames=30,
            slam_size=(320, 240),
            slam_seed=DEMO_SLAM_SEED,
        ),  # fmt: skip
        train_overrides=("logger=none", "callbacks.image_logger=null"),
        miou_stride=5,
        slam_repeats=2,
    ),
}


ROWS = (
    # the row's name (its run folder), its label, its variant (configs/variants.yaml), the model
    ("none", "no filter", "none", None),
    ("labels", "ground-truth masks", "oracle", None),
    ("source_only", "source-only", "semantic", "source_only"),
    ("adabn", "AdaBN", "semantic", "adabn"),
    ("adapted", "adapted", "semantic", "adapted"),
    ("adapted_geometry", "adapted + geometry", "semantic_geometry", "adapted"),
)
VARIANTS = tuple(
    replace(read_variants()[variant], name=name, label=label, model=model)
    for name, label, variant, model in ROWS
)
"""The demo's SLAM rows: variants of ``configs/variants.yaml`` (segmenter and filters), each
under the demo's own name and label, with the exported model it runs."""
TRAININGS = {"source_only": "source_only", "adapted": "adaptsegnet"}
"""Training run name -> ``model/method``; both start from the packaged init."""
MODELS = {"source_only": "source_only", "adabn": "source_only", "adapted": "adapted"}
"""Exported model -> the training whose last checkpoint it is."""
ADABN = "adabn"
"""The model exported with target BatchNorm statistics (AdaBN)."""


# ------------------------------------------------------------------------------- stages


def check_sequence(path: Path, option: str) -> None:
    """Everything the SLAM, mIoU and report stages read from a sequence, checked up front:
    a TUM RGB-D folder, whole 8-bit colour frames, ``labels/`` for each, a ``groundtruth.txt``."""
    from uss_slam.core.tum_io import read_trajectory
    from uss_slam.slam_eval.sequence import TumSequence

    if not path.is_dir():
        raise UssSlamError(f"{option}: {path} is not a folder")
    try:
        TumSequence(path, load_labels=True).check_colour_frames()
        gt = path / "groundtruth.txt"
        if not gt.is_file():
            raise UssSlamError(f"{gt}: not found (the demo reports ATE)")
        if len(read_trajectory(gt)) < 2:
            raise UssSlamError(f"{gt}: expected at least 2 poses 'timestamp tx ty tz qx qy qz qw' "
                               "(the demo reports ATE)")  # fmt: skip
    except UssSlamError as error:
        raise UssSlamError(f"{option}: {error}") from error


def stage_data(data: Path, spec: DemoData, force: bool, quiet: bool) -> str:
    if not force and synthetic_data.is_complete(data, spec):
        print(f"reusing the complete demo data set in {data} (same arguments)")
        print(synthetic_data.summarize(data))
        return "reused"
    # replaces an earlier (other-sized) data set only once the new one is complete
    synthetic_data.render_demo_data(data, spec, overwrite=True, progress=not quiet)
    print(synthetic_data.summarize(data))
    return "rendered"


def _data_key(data: Path) -> str:
    record = data / synthetic_data.RECORD
    if not record.is_file():
        raise UssSlamError(f"{record}: missing; the data stage did not complete")
    return record.read_text(encoding="utf-8")


def _json(path: Path) -> Any:  # a JSON record the demo wrote
    return json.loads(path.read_text(encoding="utf-8"))


def train_overrides(
    plan: Plan, data: Path, name: str, threads: int | None = None, init: Path | None = None
) -> list[str]:
    """The ``uss-train`` overrides of training run ``name`` (``adapted`` / ``source_only``),
    starting from ``init`` (default: the packaged init); ``threads`` overrides the experiment's
    ``num_threads``."""
    init = demo_init_path() if init is None else init
    return [
        f"experiment={plan.experiment}",
        f"model/method={TRAININGS[name]}",
        path_override("paths.data_dir", data),
        f"run_name={plan.experiment}_{name}",
        f"model.net.weights_path={hydra_value(str(init))}",
        *plan.data.train_overrides(data),  # the data set's folders, where not the shipped ones
        *plan.train_overrides,
        *([] if threads is None else [f"num_threads={threads}"]),
    ]


def _train(run_dir: Path, overrides: list[str]) -> str:
    metrics = run_training(run_dir, overrides, resume=True)
    write_json_atomic(run_dir / "metrics.json", metrics)
    miou = metrics.get("val/mIoU")
    start = metrics.get("resumed_from_iteration")
    return (
        "trained"
        + ("" if start is None else f" (went on from iteration {int(start)})")
        + ("" if miou is None else f", val/mIoU {miou:.3f}")
    )


def stage_train(
    run_dir: Path, overrides: list[str], data_key: str, force: bool, init: Path | None = None
) -> str:
    """Train into ``run_dir`` unless done with the same key (the init's content in it); an
    interrupted training of the same key goes on from its ``last.ckpt`` (``--force``: anew)."""
    init = demo_init_path() if init is None else init
    stage = Stage(
        run_dir,
        key={
            "stage": "train",
            "overrides": overrides,
            "data": data_key,
            "init": file_sha256(init),
        },
        outputs=(*map(Path, TRAINING_OUTPUTS), Path("metrics.json")),
        resume_from=RESUME_FROM,
    )
    return run_stage(stage, lambda: _train(run_dir, overrides), force)


def adabn_prepare(target: Sequence[Path]) -> Callable[[Any], object]:
    """The ``export_checkpoint`` ``prepare`` of the AdaBN model: BatchNorm statistics of evenly
    spaced unlabelled ``target`` frames, as ``uss-experiments``' AdaBN exports
    (:func:`~uss_slam.train.precise_bn.adabn`, same image count and batch size)."""
    from uss_slam.datasets.transforms import eval_transform
    from uss_slam.datasets.tum import TUMFrames
    from uss_slam.train.precise_bn import adabn

    from .experiments.plan import ADABN_BATCH_SIZE, ADABN_IMAGES

    def prepare(net: Any) -> None:
        frames = TUMFrames(list(target), labels=False, transform=eval_transform())
        adabn(net, frames, images=ADABN_IMAGES, batch_size=ADABN_BATCH_SIZE)

    return prepare


def stage_export(
    run_dir: Path,
    onnx_path: Path,
    force: bool,
    adabn_target: Sequence[Path] | None = None,
    experiment: str | None = None,
) -> str:
    """Export ``run_dir``'s last checkpoint to ``onnx_path``; with ``adabn_target`` (target
    frame folders), with AdaBN statistics of those frames (``experiment``: its metadata name)."""
    from .experiments.plan import ADABN_BATCH_SIZE, ADABN_IMAGES

    ckpt = select_checkpoint(run_dir)
    key: dict[str, Any] = {"stage": "export", "checkpoint": str(ckpt), "sha256": file_sha256(ckpt)}
    if adabn_target is not None:
        key["adabn"] = {"images": ADABN_IMAGES, "batch_size": ADABN_BATCH_SIZE,
                        "target": [str(p) for p in adabn_target]}  # fmt: skip
    stage = Stage(
        onnx_path.parent / f".{onnx_path.stem}",  # holds only the stamp
        key=key,
        outputs=(onnx_path.absolute(),),
    )

    def work() -> str:
        from uss_slam.export import export_checkpoint

        options: dict[str, Any] = {}
        if adabn_target is not None:
            options = {"prepare": adabn_prepare(adabn_target), "experiment": experiment}
        result = export_checkpoint(ckpt, onnx_path, **options)  # experiment: the run_name
        verify = result.verify
        return (
            f"exported {ckpt.name}"
            + (", target BatchNorm statistics (AdaBN)" if adabn_target is not None else "")
            + f", verified: max |logit diff| {verify['max_abs_logit_diff']:.1e}, labels equal "
            f"{100 * verify['label_agreement']:.2f}%"
        )

    return run_stage(stage, work, force)


def miou_scores(sequence: Path, models: dict[str, Path], stride: int) -> dict[str, Any]:
    """mIoU and per-class IoU (``None``: class in neither truth nor prediction) of each ONNX
    model on every ``stride``-th frame of ``sequence``'s labels, with frames and ms per frame."""
    from uss_slam.core.seg_metrics import iou_report
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter
    from uss_slam.slam_eval.sequence import TumSequence

    from .evaluate import LabelledFrame, evaluate_frames

    seq = TumSequence(str(sequence), load_labels=True, stride=stride)
    frames = []
    for k in range(len(seq)):
        frame = seq.load(k)
        assert frame.labels is not None  # load_labels=True
        frames.append(LabelledFrame(str(k), frame.rgb, frame.labels))
    scores: dict[str, Any] = {}
    for name, model in models.items():
        result = evaluate_frames(OnnxSegmenter(model, threads=None).infer, frames, CLASS_NAMES)
        scores[name] = {
            **iou_report(result.matrix, CLASS_NAMES),
            "frames": len(frames),
            "ms_per_frame": 1000 * result.seconds / max(len(frames), 1),
        }
    return scores


def stage_miou(out: Path, sequence: Path, models: dict[str, Path], stride: int, force: bool) -> str:
    path = out / "miou.json"
    key = {
        "stage": "miou",
        "sequence": content_key(sequence),
        "stride": stride,
        "models": {name: file_sha256(p) for name, p in models.items()},
    }
    stage = Stage(out / ".miou", key=key, outputs=(path.absolute(),))

    def work() -> str:
        scores = miou_scores(sequence, models, stride)
        write_json_atomic(path, {"key": key, "scores": scores})
        return ", ".join(f"{n} mIoU {demo_report.fmt(s['mIoU'], 3)}" for n, s in scores.items())

    return run_stage(stage, work, force)


def slam_job(
    variant: Variant, sequence: Path, models: dict[str, Path], repeats: int = SLAM_REPEATS
) -> SlamJob:
    """The SLAM run of one comparison variant (``models``: export name -> ONNX file), repeated
    ``repeats`` times (``slam.repeats``; the folder holds the median run)."""
    model = None if variant.model is None else models[variant.model]
    return SlamJob(
        sequence, Segmenter.of(variant, model), variant.filters, (f"slam.repeats={repeats}",)
    )


def stage_slam(
    run_dir: Path, job: SlamJob, inputs: dict[str, str], force: bool, quiet: bool
) -> str:
    def work() -> str:
        data = run_slam(job, run_dir, progress=not quiet)
        ate = data["ate"]
        rmse = "n/a" if ate is None else f"{ate['rmse']:.4f} m"
        spread = data.get("ate_rmse_repeats")
        if spread is not None:
            rmse += (f" (median of {len(data['repeats'])}; {demo_report.fmt(spread['min'])}-"
                     f"{demo_report.fmt(spread['max'])})")  # fmt: skip
        return f"ATE RMSE {rmse}, {data['fps']:.1f} frames/s"

    stage = Stage(
        run_dir,
        key={
            "stage": "slam",
            "overrides": job.overrides(),
            "defaults": slam_defaults_key(),
            "inputs": inputs,
        },
        outputs=(Path("metrics.json"),),
    )
    return run_stage(stage, work, force)


def stage_report(
    out: Path, plan: Plan, sequence: Path, times: dict[str, float], train_dirs: dict[str, Path]
) -> str:
    slam_dir = out / "slam"
    miou_file = out / "miou.json"
    miou = _json(miou_file)["scores"] if miou_file.is_file() else {}
    rows = demo_report.summary_rows(slam_dir, VARIANTS, miou)
    table = demo_report.markdown_table(rows)
    findings = demo_report.findings(rows, demo_report.training_metrics(train_dirs.get("adapted")))
    demo_report.plot_ate_bars(
        out / "ate_rmse.png", rows, f"{sequence.name}: absolute trajectory error per variant"
    )
    demo_report.plot_aligned_trajectories(
        out / "trajectories.png",
        sequence / "groundtruth.txt",
        slam_dir,
        rows,
        f"{sequence.name}: aligned trajectories (top view)",
    )
    plots = ["ate_rmse.png", "trajectories.png"]
    from uss_slam.slam_eval.scoring.report import write_comparison

    runs = {v.name: _json(slam_dir / v.name / "metrics.json") for v in VARIANTS}
    write_comparison(slam_dir, runs)
    val = {name: demo_report.final_val_miou(d) for name, d in train_dirs.items()}
    summary = {
        "experiment": plan.experiment,
        "sequence": str(sequence),
        "init": {"path": str(demo_init_path()), "sha256": file_sha256(demo_init_path())},
        "slam_repeats": plan.slam_repeats,
        "rows": rows,
        "findings": findings,
        "val_mIoU": val,
        "stage_seconds": times,
    }
    write_json_atomic(out / "summary.json", summary)
    demo_report.write_report(
        out / "report.md",
        title=f"{sequence.name} (experiment `{plan.experiment}`)",
        slam_seed=plan.data.slam_seed, slam_repeats=plan.slam_repeats,
        miou_stride=plan.miou_stride, table=table, findings=findings, val=val,
        variants=VARIANTS, times=times,
    )  # fmt: skip
    print(f"\n{table}\n")
    for finding in findings:
        print(finding)
    print(f"\n{demo_report.CAVEAT}\n")
    verdict = demo_compare(out, sequence)
    return f"{out / 'report.md'} ({len(plots)} plots); {out / 'compare' / 'report.md'}: {verdict}"


COMPARE_LABELS = 20
"""Labelled frames of the SLAM sequence the closing ``uss-eval compare`` uses (its verdict)."""


def demo_compare(out: Path, sequence: Path) -> str:
    """The closing report: ``uss-eval compare`` of the three exported models on the SLAM
    sequence (validators, mask agreement, contact sheet) with ``COMPARE_LABELS`` of its labelled
    frames, into ``OUT/compare/`` (printed); returns its last line, the verdict."""
    from .evaluate.compare_cli import compare, plan_compare

    models = [out / "exports" / f"{name}.onnx" for name in MODELS]
    source = next((out / "data" / "voc").rglob("JPEGImages"), None)
    plan = plan_compare(
        models, [sequence], labels=[sequence / "labels"], label_frames=COMPARE_LABELS, source=source
    )
    print(f"uss-eval compare {' '.join(str(m) for m in models)} --sequence {sequence} --labels "
          f"{sequence / 'labels'} --label-frames {COMPARE_LABELS}" + (f" --source {source}" if source else ""))  # fmt: skip
    # the tables are in OUT/compare/report.md; the demo's own table stays the one printed
    return compare(plan, out / "compare", quiet=True, tables=False)["verdict"]


# ------------------------------------------------------------------------------- main


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uss-demo",
        description="The end-to-end demo on synthetic data: generate data, continue the "
        "packaged pretrained init source-only and with adaptation, export both and source-only "
        "with target BatchNorm statistics (AdaBN) to ONNX, run the SLAM harness three times "
        "each with six variants (no filter, ground-truth masks, source-only, AdaBN, adapted, "
        "adapted + geometry), print one table and write OUT/report.md. Complete stages with "
        "the same inputs are reused.",
    )
    parser.add_argument("--out", type=path_argument, default=Path("outputs/demo"),
                        help="output folder (default: outputs/demo)")  # fmt: skip
    parser.add_argument("--experiment", choices=sorted(PLANS), default="demo",
                        help="demo (default; minutes) or ci (tiny data, seconds of training)")  # fmt: skip
    parser.add_argument("--sequence", default="walking_xyz", type=home_expanded,
                        help="SLAM sequence: a name under OUT/data/slam/ (walking_xyz, "
                             "static_xyz) or a TUM RGB-D folder with labels/ and "
                             "groundtruth.txt (default: walking_xyz)")  # fmt: skip
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--reuse", dest="force", action="store_false",
                       help="reuse stages already complete with the same inputs, and go on "
                            "with a training stopped half-way (default)")  # fmt: skip
    group.add_argument("--force", dest="force", action="store_true",
                       help="redo every stage (trainings anew from the init)")  # fmt: skip
    parser.set_defaults(force=False)  # (store_false would make --reuse's default True)
    parser.add_argument("--until", choices=STAGES, default="report", metavar="STAGE",
                        help="stop after this stage: " + ", ".join(STAGES) + " (default: "
                             "report, all; data renders only the data set into OUT/data)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--train-threads", type=THREADS_ARG, default=None, metavar="N",
                        help="torch threads of the two trainings (default: the experiment's "
                             "num_threads, 2 for demo; 1 is faster on a busy shared machine)")  # fmt: skip
    return given_once(parser)


def _steps(until: str) -> int:
    """Progress steps of the stages up to ``until``."""
    per_stage = {"data": 1, "train": len(TRAININGS), "export": len(MODELS), "miou": 1,
                 "slam": len(VARIANTS), "report": 1}  # fmt: skip
    return sum(per_stage[s] for s in STAGES[: STAGES.index(until) + 1])


def run_demo(
    out: Path, experiment: str = "demo", sequence: str = "walking_xyz", *,
    force: bool = False, quiet: bool = False, train_threads: int | None = None,
    until: str = "report",
) -> dict[str, Any] | None:  # fmt: skip
    """Run the stages (see the module doc) up to ``until``; returns the content of
    ``OUT/summary.json`` (None when stopped before the report). ``out`` is locked while they
    run: a second demo into it stops at once (:func:`~uss_slam.core.files.output_lock`)."""
    plan = PLANS[experiment]
    out = Path(out)
    if train_threads is not None and not 1 <= train_threads <= MAX_THREADS:
        raise UssSlamError(
            f"--train-threads: expected {THREADS_ARG.expected()}, got {train_threads}"
        )
    if until not in STAGES:
        raise UssSlamError(f"--until {until}: not a stage ({', '.join(STAGES)})")
    output_folder(out, "--out", inputs=[("--sequence", sequence)] if sequence else ())
    check_output_owner(out, "uss-demo", "--out")  # a uss-slam run's report.md, ...
    if until != "data":  # before the data stage's minutes
        need_working_folder(f"--until {until}", "the training stage", "--until data")
    check_filters({v.name: v for v in VARIANTS}, list(filter_classes()))
    data = out / "data"
    # A bad --sequence fails here, before any work (a name: after the data stage made it)
    if sequence in synthetic_data.SLAM_PRESETS and not Path(sequence).is_dir():
        seq_path = data / "slam" / sequence
    else:
        presets = ", ".join(synthetic_data.SLAM_PRESETS)
        seq_path = input_folder(
            sequence, "--sequence",
            f"expected a TUM sequence folder or one of the demo's SLAM sequences ({presets})",
        )  # fmt: skip
        check_sequence(seq_path, f"--sequence {sequence}")  # also with --until data: before work
    with output_lock(out, "--out"):
        return _run_stages(out, plan, data, seq_path, sequence, force, quiet, train_threads, until)


def _run_stages(
    out: Path, plan: Plan, data: Path, seq_path: Path, sequence: str, force: bool, quiet: bool,
    train_threads: int | None, until: str,
) -> dict[str, Any] | None:  # fmt: skip
    """The stages of :func:`run_demo` once its arguments are checked and ``out`` is locked."""
    progress = Progress(total=_steps(until))
    progress.run("data", f"data: {plan.experiment} data set -> {data}",
                 lambda: stage_data(data, plan.data, force, quiet))  # fmt: skip
    if until == "data":
        return _stopped(progress, until, out)
    if seq_path.parent == data / "slam":
        check_sequence(seq_path, f"--sequence {sequence}")
    data_key = _data_key(data)
    train_dirs = {name: out / "train" / name for name in TRAININGS}
    for name, run_dir in train_dirs.items():
        overrides = train_overrides(plan, data, name, train_threads)
        progress.run("train", f"train {name}: uss-train {' '.join(overrides)}",
                     lambda o=overrides, d=run_dir: stage_train(d, o, data_key, force))  # fmt: skip
    if until == "train":
        return _stopped(progress, until, out)
    models = {name: out / "exports" / f"{name}.onnx" for name in MODELS}
    target = [data / folder for folder in plan.data.target_folders()]
    for name, model in models.items():
        adabn = (target, f"{plan.experiment}_{ADABN}") if name == ADABN else (None, None)
        progress.run("export", f"export {name} -> {model}",
                     lambda d=train_dirs[MODELS[name]], m=model, a=adabn: stage_export(
                         d, m, force, *a))  # fmt: skip
    if until == "export":
        return _stopped(progress, until, out)
    progress.run("miou", f"mIoU on {seq_path.name}",
                 lambda: stage_miou(out, seq_path, models, plan.miou_stride, force))  # fmt: skip
    if until == "miou":
        return _stopped(progress, until, out)
    inputs = {name: file_sha256(model) for name, model in models.items()}
    inputs["sequence"] = content_key(seq_path)
    for v in VARIANTS:
        job = slam_job(v, seq_path, models, plan.slam_repeats)
        used = {k: inputs[k] for k in ("sequence", v.model or v.segmenter) if k in inputs}
        progress.run("slam", f"slam {v.name}: uss-slam {' '.join(job.overrides())}",
                     lambda v=v, j=job, u=used: stage_slam(
                         out / "slam" / v.name, j, u, force, quiet))  # fmt: skip
    if until == "slam":
        return _stopped(progress, until, out)
    progress.run("report", "report",
                 lambda: stage_report(out, plan, seq_path, progress.times, train_dirs))  # fmt: skip
    summary = _json(out / "summary.json")
    total = time.perf_counter() - progress.start
    print(f"uss-demo: done in {total:.1f} s; report: {out / 'report.md'}")
    return summary


def _stopped(progress: Progress, until: str, out: Path) -> None:
    total = time.perf_counter() - progress.start
    print(f"uss-demo: stopped after the {until} stage (--until {until}) in {total:.1f} s; {out}")
    return None


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with exit_on_user_error("uss-demo"):
        run_demo(args.out, args.experiment, args.sequence, force=args.force, quiet=args.quiet,
                 train_threads=args.train_threads, until=args.until)  # fmt: skip
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

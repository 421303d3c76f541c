"""``uss-experiments``: the USS-SLAM paper's tables by one command (``configs/experiments.yaml``).

Stages, in order, each printed with its time (``stages=[...]`` runs a subset):

1. ``data``: synthetic data rendered into ``out_dir/data`` (``uss-synth demo`` for training;
   each evaluation sequence with a held-out seed), or the real folders of ``data.real`` checked.
2. ``train``: the training grid (source-only; adapted with each discriminator depth; each loss
   weight combination; each seed; T0's target oracle) as one Hydra multirun through
   ``launcher``.
3. ``export``: each complete training's checkpoint to ``out_dir/exports/<model>/``, and each
   source-only one with target BatchNorm statistics (T0's AdaBN) to ``exports/adabn_s<seed>/``.
4. ``slam``: a Hydra multirun of the segmentation evaluations (each model on every labelled
   evaluation sequence; T0's rows also on the source validation split) and the SLAM runs (each
   system, sequence and variant; each model).
5. ``tables``: ``runs.csv`` (one row per job), ``tables.md``, ``tables.json`` and ``plots/``.

Every job is cached (a stamp with the key of its inputs, written after its result): a rerun
launches only the jobs that are missing, failed or whose inputs changed. A failed job never
stops the others; the tables mark it and list why. Bad keys (scale, launcher, training
experiment, method, depth sweep, sequence, variant, system, stage, CRF parameters, T0's
``grid.adabn`` / ``grid.oracle``) and missing or incomplete data folders are one error line
before any work starts.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import hydra
from omegaconf import DictConfig

from uss_slam.core.cli import (
    check_stdout_open,
    exit_on_user_error,
    hydra_task,
    print_output,
    run_hydra_app,
)
from uss_slam.core.files import output_lock
from uss_slam.pipelines.runs import policy_note
from uss_slam.pipelines.stages import Progress

from . import tables as tbl
from .data import Data, stage_data
from .experiment import Experiment, check, check_choices, eval_seed
from .grid import AdaBNCell, method_overrides
from .jobs import reason_of, stage_of
from .keys import given
from .launch import KEPT, NOT_RUN, Launch, describe_plan, launch, result_rows, status_of
from .plan import (
    ADABN_BATCH_SIZE,
    ADABN_IMAGES,
    blocked_jobs,
    checkpoint_policy,
    existing_exports,
    harness_repeats,
    model_path,
    model_stage,
    plan_slam,
    plan_train,
    source_val_held_out,
)
from .validate import check_job_configs
from .warm_start import describe_init, init_header, stage_init

PROG = "uss-experiments"


def run_experiments(cfg: DictConfig) -> dict[str, Any]:
    """Run the configured stages; returns ``{"rows": runs.csv rows, "tables": tables.json}``
    (``{}`` for a dry run)."""
    if bool(cfg.get("dry_run")):
        check_stdout_open()  # the plan is the product: before the configs' checks and warnings
    exp = check(cfg)
    if bool(exp.cfg.get("dry_run")):
        return _run_experiments(exp)
    with output_lock(exp.out, "out_dir"):  # a second uss-experiments into out_dir stops at once
        return _run_experiments(exp)


def _run_experiments(exp: Experiment) -> dict[str, Any]:
    out = exp.out
    out.mkdir(parents=True, exist_ok=True)
    dry = bool(exp.cfg.get("dry_run"))
    progress = Progress(total=len(exp.stages))
    data_holder: dict[str, Data] = {}
    # every job's config composed and checked before any work (the data stage included)
    t0 = time.perf_counter()
    n_train, n_slam = check_job_configs(exp, stage_data(exp, run=False, dry=True)[0])
    print(
        f"configs: {n_train} training and {n_slam} SLAM configs composed and checked in "
        f"{time.perf_counter() - t0:.1f} s"
    )

    def do_data() -> str:
        run = "data" in exp.stages and not dry
        data, status = stage_data(exp, run=run, dry=dry)
        if exp.init.pretrained:  # the warm start: the init every training starts from
            status += ", " + stage_init(exp, data, run=run, dry=dry)
        data_holder["data"] = data
        return status

    if "data" in exp.stages and not dry:
        progress.run("data", f"data -> {out / 'data'}", do_data)
    else:
        print(f"data: {do_data()}")
    data = data_holder["data"]

    train_jobs = plan_train(exp, data)
    exp.train_specs.update({j.id: j.spec for j in train_jobs})
    launches: dict[str, Launch] = {}
    if dry:
        parts = [describe_init(exp), describe_plan(exp, "train", train_jobs, set()),
                 describe_exports(exp, data)]  # fmt: skip
        exports = existing_exports(exp, data)
        slam_jobs = plan_slam(exp, data, exports)
        blocked = {j.id for j in slam_jobs if j.needs is not None and j.needs not in exports}
        parts.append(describe_plan(exp, "slam", slam_jobs, blocked))
        # the plan is a dry run's product: stdout that fails (full, closed) is its error, and
        # a closed pipe (| head -c0) exit code 1 without a word, as uss-traj's
        code = print_output("\n".join(p for p in parts if p is not None))
        if code:
            raise SystemExit(code)
        return {}
    if "train" in exp.stages:
        progress.run(
            "train",
            f"train: {len(train_jobs)} training jobs",
            lambda: _launch_status(launches, "train", launch(exp, "train", train_jobs, set())),
        )
    export_failures: dict[str, str] = {}
    export_rows: list[dict[str, Any]] = []
    if "export" in exp.stages:
        progress.run(
            "export",
            f"export: {checkpoint_policy(exp)} checkpoints -> ONNX",
            lambda: stage_exports(exp, data, export_failures, export_rows),
        )
    exports = existing_exports(exp, data)
    if "export" not in exp.stages:  # the models an earlier run exported (runs.csv keeps them)
        export_rows = [
            {**_export_row(cell), "status": "ok"}
            for cell in exp.grid.models
            if cell.model in exports
        ]
    slam_jobs = plan_slam(exp, data, exports)
    blocked = blocked_jobs(exp, slam_jobs, exports, export_failures)
    if "slam" in exp.stages:
        progress.run(
            "slam",
            f"slam: {len(slam_jobs)} segmentation evaluations and SLAM runs",
            lambda: _launch_status(launches, "slam", launch(exp, "slam", slam_jobs, set(blocked))),
        )
    rows: list[dict[str, Any]] = []
    for job in train_jobs:
        status, reason, result = status_of(exp, job, {}, launches)
        rows += result_rows(job, status, reason, result, exp.grid.sequences)
    rows += export_rows
    for job in slam_jobs:
        status, reason, result = status_of(exp, job, blocked, launches)
        rows += result_rows(job, status, reason, result, exp.grid.sequences)
    tables: dict[str, Any] = {}
    if "tables" in exp.stages:

        def do_tables() -> str:
            tbl.write_runs(out / "runs.csv", rows)
            read = tbl.read_runs(out / "runs.csv")
            tables.update(
                tbl.write_tables(
                    out,
                    read,
                    exp.cfg["tables"]["n_layers"],
                    header=_header(exp, data),
                    policy=checkpoint_policy(exp),
                )
            )
            return (
                f"{out / 'tables.md'}, {out / 'tables.json'}, {out / 'runs.csv'}, {out / 'plots'}"
            )

        progress.run("tables", "tables", do_tables)
    bad = sorted(
        {
            r["id"]
            for r in rows
            if (r["status"] != "ok" and r["reason"] != NOT_RUN)
            or str(r.get("reason") or "").startswith(KEPT)
        }
    )
    total = time.perf_counter() - progress.start
    print(
        f"{PROG}: done in {total:.1f} s; {len({r['id'] for r in rows})} jobs, "
        f"{len(bad)} without a result"
        + (f" (see the Failures table of {out / 'tables.md'})" if bad and tables else "")
    )
    return {"rows": rows, "tables": tables, "failed": bad}


def _launch_status(launches: dict[str, Launch], stage: str, result: Launch) -> str:
    launches[stage] = result
    if result.returncode is None:
        return "every job complete already (reused)"
    n = len(result.pending)
    return f"ran {n} job{'' if n == 1 else 's'} (multirun exit code {result.returncode})"


def stage_exports(
    exp: Experiment, data: Data, failures: dict[str, str], rows: list[dict[str, Any]]
) -> str:
    """Export every complete training not exported yet, and each AdaBN model of a complete
    source-only training (in this process); a failure is recorded for the tables and blocks
    that model's jobs."""
    from uss_slam.export import export_checkpoint
    from uss_slam.pipelines.runs import select_checkpoint

    done = reused = 0
    for cell in exp.grid.models:
        row = _export_row(cell)
        stage = model_stage(exp, data, cell)
        if stage is None:
            continue  # training not complete: its own row says why
        if stage.complete():
            reused += 1
            rows.append({**row, "status": "ok"})
            continue
        t0 = time.perf_counter()
        stage.start()
        training = exp.grid.training(cell.model)
        try:
            export_checkpoint(
                select_checkpoint(
                    stage_of(exp.out, exp.train_specs[training.id], training.id).folder,
                    checkpoint_policy(exp),
                ),
                model_path(exp, cell),
                **(_adabn_options(data, cell) if isinstance(cell, AdaBNCell) else {}),
            )
        except Exception as error:  # recorded, like a failed job, so that the others go on
            failures[cell.model] = reason_of(error)
            rows.append({**row, "status": "failed", "reason": failures[cell.model]})
            print(f"  export {cell.model} failed: {failures[cell.model]}", flush=True)
            continue
        stage.finish()
        done += 1
        rows.append({**row, "status": "ok", "seconds": time.perf_counter() - t0})
    return f"{done} exported, {reused} reused"


def _export_row(cell: Any) -> dict[str, Any]:
    """The runs.csv row of a model's export, without its status."""
    return {
        "kind": "export",
        "id": f"exports/{cell.model}",
        "folder": f"exports/{cell.model}",
        **cell.describe(),
    }


def _adabn_options(data: Data, cell: AdaBNCell) -> dict[str, Any]:
    """``export_checkpoint`` options of an AdaBN model: its own name, and BatchNorm statistics
    recomputed on evenly spaced unlabelled target training frames before the trace."""
    from uss_slam.datasets.transforms import eval_transform
    from uss_slam.datasets.tum import TUMFrames
    from uss_slam.train.precise_bn import adabn

    def prepare(net: Any) -> None:
        target = TUMFrames(data.target, labels=False, transform=eval_transform())
        adabn(net, target, images=ADABN_IMAGES, batch_size=ADABN_BATCH_SIZE)

    return {"experiment": cell.model, "prepare": prepare}


def describe_exports(exp: Experiment, data: Data) -> str:
    """The export stage's plan (dry run): every model not exported yet."""
    pending = []
    for cell in exp.grid.models:
        stage = model_stage(exp, data, cell)
        if stage is None or not stage.complete():
            pending.append(cell)
    lines = [
        f"export: {len(exp.grid.models)} models, {len(exp.grid.models) - len(pending)} "
        f"complete, {len(pending)} to export (each once its training is complete)"
    ]
    for cell in pending:
        note = ""
        if isinstance(cell, AdaBNCell):
            note = (
                f" (AdaBN: {cell.source.id}'s checkpoint, BatchNorm statistics of "
                f"{ADABN_IMAGES} target training frames)"
            )
        lines.append(f"  to export: exports/{cell.model}{note}")
    return "\n".join(lines)


def _header(exp: Experiment, data: Data) -> list[str]:
    cfg = exp.cfg
    grid = cfg["grid"]
    lines = [
        f"# USS-SLAM experiments: scale {cfg['scale_name']}",
        "",
        f"- data: {'synthetic (out_dir/data)' if exp.synthetic else 'real'}; training "
        f"experiment `{cfg['train']['experiment']}`; methods {', '.join(grid['methods'])}; "
        f"discriminator depths {', '.join(map(str, grid['n_layers']))} (for "
        f"{', '.join(grid.get('depth_sweep') or []) or 'no method'}; the others at "
        f"{cfg['tables']['n_layers']}); seeds "
        f"{', '.join(map(str, grid['seeds']))}"
        + (f"; loss weights {given(grid['loss'])}" if given(grid.get("loss")) else "")
        + "".join(
            f"; {method}: `{' '.join(settings)}`"
            for method, settings in method_overrides(grid.get("method_overrides")).items()
            if settings
        ),
        init_header(exp),
        f"- evaluation sequences: {', '.join(exp.grid.sequences)}"
        + (
            ""
            if not exp.synthetic
            else " (rendered with held-out seeds "
            + ", ".join(str(eval_seed(cfg, s)) for s in exp.grid.sequences)
            + ")"
        ),
        f"- systems: {', '.join(exp.grid.systems)}; variants: {', '.join(exp.grid.variants)}"
        + f" (harness: median of {harness_repeats(cfg)} run(s) per job"
        + (
            ""
            if "orbslam3" not in exp.grid.systems
            else f"; ORB-SLAM3: median of {cfg['slam']['orbslam3']['repeats']} runs per job"
        )
        + ")",
        f"- segmentation metrics on 1 labelled frame in {cfg['segeval']['stride']} of "
        + (", ".join(data.labelled) if data.labelled else "no sequence (none has labels/)"),
        "- each cell: mean ± sample s.d. over seeds (n = successful jobs; T0: mean ± s.e.); "
        "runs.csv has every job",
        *_t0_header(exp, data),
        f"- {policy_note(checkpoint_policy(exp))}"
        + (
            f"; synthetic shift {cfg['data']['synthetic'].get('shift', 'tum_like')}"
            if exp.synthetic
            else ""
        ),
        "",
    ]
    return lines


def _t0_header(exp: Experiment, data: Data) -> list[str]:
    """What T0's reference rows and in-domain column are in this run."""
    grid = exp.cfg["grid"]
    parts = [
        f"AdaBN on {ADABN_IMAGES} evenly spaced target training frames"
        if grid.get("adabn")
        else "no AdaBN (grid.adabn=false)",
        "oracle trained on the labelled target training frames"
        if grid.get("oracle")
        else "no oracle (grid.oracle=false: no closure)",
    ]
    stride = exp.cfg["segeval"].get("source_val_stride")
    if stride is None:
        parts.append("no in-domain column (segeval.source_val_stride=null)")
    else:
        held_out = source_val_held_out(exp, data)
        parts.append(
            f"in domain: the source VOC tree's val split (1 image in {stride}), "
            + ("held out from training" if held_out else "NOT held out: the trainings read it")
        )
    return [f"- T0: {'; '.join(parts)}"]


@hydra.main(version_base="1.3", config_path="../../configs", config_name="experiments")
def _app(cfg: DictConfig) -> None:
    result = hydra_task(PROG, run_experiments, cfg)
    if result is None:  # under -m, a sweep that failed: the other sweeps go on
        return
    if result.get("failed"):
        failed = result["failed"]
        print(
            f"{PROG}: error: {len(failed)} job{'' if len(failed) == 1 else 's'} without a new "
            f"result: {', '.join(failed)} (their reasons: the Failures table, runs.csv)",
            file=sys.stderr,
            flush=True,
        )
        sys.exit(1)


def main() -> None:
    """Console script: the scale / launcher choices checked first, then the Hydra app (config
    errors and an output folder Hydra cannot create are one line, as in the other scripts)."""
    with exit_on_user_error(PROG):
        check_choices(sys.argv[1:])
    run_hydra_app(PROG, _app)


if __name__ == "__main__":
    main()

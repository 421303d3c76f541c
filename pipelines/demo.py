"""``uss-demo``: the whole story on synthetic data (what ``make demo`` runs after installing).

Stages, each printed with its elapsed time, each reused when already complete with the same
inputs (a ``.uss-demo.json`` stamp in its folder; ``--force`` redoes everything):

1. ``data``: the synthetic data set (``uss-synth demo``: source VOC tree, target training,
   validation and SLAM sequences) in ``OUT/data``.
2. ``train``: the ``--experiment`` (``demo``, or ``ci`` for a seconds-long smoke run) twice: with
   adversarial adaptation and source-only (``model.adaptation=false``), into
   ``OUT/train/{adapted,source_only}`` (checkpoints/, tensorboard/, .hydra/config.yaml).
3. ``export``: the best checkpoint (by target val mIoU) of each run to
   ``OUT/exports/{adapted,source_only}.onnx`` with ``uss-export``'s verification.
4. ``miou``: each exported model's mIoU (and per-class IoU) on the SLAM sequence's labels
   (target domain; every ``MIOU_STRIDE``-th frame) through :class:`OnnxSegmenter`.
5. ``slam``: the SLAM harness on ``OUT/data/slam/<--sequence>``: no filter; ``labels`` (oracle);
   source-only ONNX; adapted ONNX; adapted ONNX + geometry, into ``OUT/slam/<variant>/``
   (plus ``OUT/slam/comparison.md`` in the harness's baseline-vs-each format).
6. ``report``: one table (printed) and ``OUT/report.md`` with ``ate_rmse.png`` (ATE per variant),
   ``trajectories.png`` (every aligned estimate vs ground truth) and each run's own plots;
   ``OUT/summary.json`` holds the table's numbers.

Example: ``uss-demo --out outputs/demo`` (what ``make demo`` runs; its measured time is in the README).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import file_sha256

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
STAMP = ".uss-demo.json"
MIOU_STRIDE = 10
"""Every 10th frame of the SLAM sequence is scored for mIoU (30 of the demo's 300)."""


@dataclass(frozen=True)
class Plan:
    """What ``--experiment`` changes: the data set's size and the training experiment."""

    experiment: str
    synth_args: tuple[str, ...] = ()
    train_overrides: tuple[str, ...] = ()
    miou_stride: int = MIOU_STRIDE


PLANS = {
    # `make demo`'s data set (uss-synth demo defaults: 400 VOC images, 4 x 100 target training
    # frames, 100 validation frames, 2 x 300 SLAM frames at 640x480).
    "demo": Plan("demo"),
    # Seconds-long smoke run for the tests: tiny data, 4 training iterations.
    "ci": Plan(
        "ci",
        synth_args=(
            "--voc-images",
            "8",
            "--train-frames",
            "4",
            "--val-frames",
            "4",
            "--train-size",
            "160x120",
            "--slam-frames",
            "30",
            "--slam-size",
            "320x240",
        ),  # fmt: skip
        train_overrides=("logger=none", "callbacks.image_logger=null"),
        miou_stride=5,
    ),
}


@dataclass(frozen=True)
class Variant:
    """One SLAM run of the comparison."""

    name: str
    label: str
    segmenter: str  # none | labels | the export name (adapted / source_only)
    filters: tuple[str, ...] = field(default_factory=tuple)


VARIANTS = (
    Variant("none", "no filter", "none"),
    Variant("labels", "labels (oracle)", "labels", ("semantic",)),
    Variant("source_only", "source-only ONNX", "source_only", ("semantic",)),
    Variant("adapted", "adapted ONNX", "adapted", ("semantic",)),
    Variant("adapted_geometry", "adapted ONNX + geometry", "adapted", ("semantic", "geometry")),
)
TRAININGS = {"adapted": True, "source_only": False}
"""Training run name -> ``model.adaptation``."""


# ------------------------------------------------------------------------------- stages


class Progress:
    """Prints ``[k/N] stage ... done in X s (total Y s)``."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.count = 0
        self.start = time.perf_counter()
        self.times: dict[str, float] = {}

    def run(self, name: str, what: str, fn: Callable[[], str]) -> None:
        self.count += 1
        print(f"[{self.count}/{self.total}] {what} ...", flush=True)
        t0 = time.perf_counter()
        status = fn()
        spent = time.perf_counter() - t0
        self.times[name] = self.times.get(name, 0.0) + spent
        total = time.perf_counter() - self.start
        print(
            f"[{self.count}/{self.total}] {what}: {status} in {spent:.1f} s (total {total:.1f} s)",
            flush=True,
        )


def _stamped(folder: Path, key: dict[str, Any], force: bool) -> bool:
    """True when ``folder`` holds a complete stage made from ``key``."""
    if force:
        return False
    try:
        return json.loads((folder / STAMP).read_text()) == key
    except (OSError, json.JSONDecodeError):
        return False


def _stamp(folder: Path, key: dict[str, Any]) -> None:
    (folder / STAMP).write_text(json.dumps(key, indent=2) + "\n")


def _fresh(folder: Path) -> None:
    """Empty the stage's own output folder (under ``--out``) before redoing it."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)


def stage_data(out: Path, plan: Plan, force: bool, quiet: bool) -> str:
    from uss_slam.synthetic import cli

    argv = ["demo", "--out", str(out), *plan.synth_args]
    if force:
        argv.append("--overwrite")
    else:
        argv.append("--reuse")
    if quiet:
        argv.append("--quiet")
    reused = not force and cli._reusable(cli.build_parser().parse_args(argv))
    code = cli.main(argv)
    if code != 0:
        raise UssSlamError(f"uss-synth {' '.join(argv)} failed with exit code {code}")
    return "reused" if reused else "rendered"


def _data_key(data: Path) -> str:
    record = data / "demo.yaml"
    if not record.is_file():
        raise UssSlamError(f"{record}: missing; the data stage did not complete")
    return record.read_text()


def train_overrides(plan: Plan, data: Path, name: str, threads: int | None = None) -> list[str]:
    """The ``uss-train`` overrides of training run ``name`` (``adapted`` / ``source_only``);
    ``threads`` overrides the experiment's ``num_threads``."""
    return [
        f"experiment={plan.experiment}",
        f"model.adaptation={str(TRAININGS[name]).lower()}",
        f"paths.data_dir={data}",
        f"run_name={plan.experiment}_{name}",
        *plan.train_overrides,
        *([] if threads is None else [f"num_threads={threads}"]),
    ]


def best_checkpoint(run_dir: Path) -> Path:
    """The best-by-val-mIoU checkpoint of a training run (``last.ckpt`` if there is none)."""
    folder = run_dir / "checkpoints"
    best = sorted(folder.glob("best_*.ckpt"))
    if best:
        return best[-1]
    last = folder / "last.ckpt"
    if last.is_file():
        return last
    raise UssSlamError(f"{folder}: no checkpoint (best_*.ckpt or last.ckpt) after training")


def checkpoint_miou(ckpt: Path) -> float | None:
    """``val/mIoU`` recorded in a best checkpoint's name (``best_iter..._miou0.1234.ckpt``)."""
    match = re.search(r"_miou(\d+\.\d+)\.ckpt$", ckpt.name)
    return float(match.group(1)) if match else None


def stage_train(run_dir: Path, overrides: list[str], data_key: str, force: bool) -> str:
    key = {"stage": "train", "overrides": overrides, "data": data_key}
    if _stamped(run_dir, key, force) and any((run_dir / "checkpoints").glob("*.ckpt")):
        return "reused"
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf, open_dict

    from .train import train

    _fresh(run_dir)
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(run_dir)
        cfg.hydra.job.num = 0
        cfg.hydra.job.name = "uss-demo"
    HydraConfig().set_config(cfg)
    try:
        # What Hydra writes for `uss-train`: uss-export reads the net config from here.
        hydra_dir = run_dir / ".hydra"
        hydra_dir.mkdir(parents=True, exist_ok=True)
        job = OmegaConf.to_container(cfg, resolve=True)
        job.pop("hydra", None)  # type: ignore[union-attr]
        OmegaConf.save(OmegaConf.create(job), hydra_dir / "config.yaml")
        OmegaConf.save(OmegaConf.create(list(overrides)), hydra_dir / "overrides.yaml")
        with open_dict(cfg):
            del cfg["hydra"]
        metrics = train(cfg)
    finally:
        HydraConfig.instance().cfg = None  # type: ignore[assignment]
        GlobalHydra.instance().clear()
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    _stamp(run_dir, key)
    miou = metrics.get("val/mIoU")
    return "trained" + ("" if miou is None else f", val/mIoU {miou:.3f}")


def stage_export(run_dir: Path, onnx_path: Path, force: bool) -> str:
    ckpt = best_checkpoint(run_dir)
    key = {"stage": "export", "checkpoint": str(ckpt), "sha256": file_sha256(ckpt)}
    stamp_dir = onnx_path.parent / f".{onnx_path.stem}"
    if _stamped(stamp_dir, key, force) and onnx_path.is_file():
        return "reused"
    from .export import export_checkpoint

    onnx_path.parent.mkdir(parents=True, exist_ok=True)
    result = export_checkpoint(ckpt, onnx_path)  # experiment = the run_name
    stamp_dir.mkdir(parents=True, exist_ok=True)
    _stamp(stamp_dir, key)
    verify = result.verify
    return (
        f"exported {ckpt.name}, verified: max |logit diff| {verify['max_abs_logit_diff']:.1e}, "
        f"labels equal {100 * verify['label_agreement']:.2f}%"
    )


def confusion(pred: np.ndarray, truth: np.ndarray, n: int) -> np.ndarray:
    """``(n, n)`` counts of (truth, prediction) over pixels whose truth is a class id < n."""
    valid = truth < n
    index = truth[valid].astype(np.int64) * n + pred[valid].astype(np.int64)
    return np.bincount(index, minlength=n * n).reshape(n, n)


def iou_scores(matrix: np.ndarray) -> dict[str, Any]:
    """Per-class IoU and their mean over classes present in truth or prediction."""
    tp = np.diag(matrix).astype(np.float64)
    union = matrix.sum(0) + matrix.sum(1) - tp
    per_class = {
        name: (float(tp[k] / union[k]) if union[k] > 0 else None)
        for k, name in enumerate(CLASS_NAMES)
    }
    present = [v for v in per_class.values() if v is not None]
    return {"mIoU": float(np.mean(present)) if present else None, "IoU": per_class}


def stage_miou(out: Path, sequence: Path, models: dict[str, Path], stride: int, force: bool) -> str:
    from uss_slam.slam_eval.onnx_segmenter import OnnxSegmenter
    from uss_slam.slam_eval.sequence import TumSequence

    path = out / "miou.json"
    key = {
        "stage": "miou",
        "sequence": str(sequence),
        "stride": stride,
        "models": {name: file_sha256(p) for name, p in models.items()},
    }
    if not force and path.is_file():
        try:
            if json.loads(path.read_text()).get("key") == key:
                return "reused"
        except json.JSONDecodeError:
            pass
    seq = TumSequence(str(sequence), load_labels=True, stride=stride)
    frames = [seq.load(k) for k in range(len(seq))]
    scores: dict[str, Any] = {}
    for name, model in models.items():
        segmenter = OnnxSegmenter(model, threads=None)
        matrix = np.zeros((len(CLASS_NAMES),) * 2, np.int64)
        t0 = time.perf_counter()
        for frame in frames:
            assert frame.labels is not None
            matrix += confusion(segmenter.infer(frame.rgb), frame.labels, len(CLASS_NAMES))
        scores[name] = {
            **iou_scores(matrix),
            "frames": len(frames),
            "ms_per_frame": 1000 * (time.perf_counter() - t0) / max(len(frames), 1),
        }
    path.write_text(json.dumps({"key": key, "scores": scores}, indent=2) + "\n")
    return ", ".join(f"{n} mIoU {s['mIoU']:.3f}" for n, s in scores.items())


def slam_overrides(variant: Variant, sequence: Path, models: dict[str, Path]) -> list[str]:
    """The ``uss-slam`` overrides of one comparison run."""
    if variant.segmenter in ("none", "labels"):
        seg = [f"segmenter={variant.segmenter}"]
    else:
        seg = ["segmenter=onnx", f"segmenter.path={models[variant.segmenter]}"]
    return [f"sequence.path={sequence}", *seg, f"filters=[{','.join(variant.filters)}]"]


def stage_slam(
    run_dir: Path, overrides: list[str], inputs: dict[str, str], force: bool, quiet: bool
) -> str:
    key = {"stage": "slam", "overrides": overrides, "inputs": inputs}
    if _stamped(run_dir, key, force) and (run_dir / "metrics.json").is_file():
        return "reused"
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    from uss_slam.slam_eval.run import run

    _fresh(run_dir)
    HydraConfig.instance().cfg = None  # type: ignore[assignment]
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(
            "slam_eval",
            overrides=[*overrides, f"out_dir={run_dir}", f"progress={str(not quiet).lower()}"],
        )
    GlobalHydra.instance().clear()
    data = run(cfg)
    _stamp(run_dir, key)
    ate = data["ate"]
    rmse = "n/a" if ate is None else f"{ate['rmse']:.4f} m"
    return f"ATE RMSE {rmse}, {data['fps']:.1f} frames/s"


# ------------------------------------------------------------------------------- report


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "—"
    return f"{value:.{digits}f}"


def summary_rows(slam_dir: Path, miou: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per variant: the numbers of the table (from each run's metrics.json)."""
    rows = []
    for v in VARIANTS:
        m = json.loads((slam_dir / v.name / "metrics.json").read_text())
        ate = m["ate"] or {}
        if v.segmenter == "labels":
            seg_iou: dict[str, Any] = {"mIoU": 1.0, "IoU": dict.fromkeys(CLASS_NAMES, 1.0)}
        else:
            seg_iou = miou.get(v.segmenter, {"mIoU": None, "IoU": {}})
        rows.append(
            {
                "variant": v.name,
                "label": v.label,
                "segmenter": m["segmenter"],
                "filters": list(v.filters),
                "ate_rmse": ate.get("rmse"),
                "ate_mean": ate.get("mean"),
                "ate_median": ate.get("median"),
                "ate_std": ate.get("std"),
                "tracked_fraction": m["tracked_fraction"],
                "fps": m["fps"],
                "segmentation_ms": m["segmentation"]["wall_ms"],
                "mIoU": seg_iou["mIoU"],
                "person_IoU": seg_iou["IoU"].get("person"),
            }
        )
    return rows


TABLE_HEADER = (
    "| variant | filters | ATE RMSE [m] | Mean [m] | Median [m] | S.D. [m] | tracked | "
    "frames/s | seg. [ms/frame] | mIoU | person IoU |"
)


def markdown_table(rows: list[dict[str, Any]]) -> str:
    lines = [TABLE_HEADER, "|" + "---|" * TABLE_HEADER.count(" | ") + "---|"]
    for r in rows:
        lines.append(
            f"| {r['label']} | {'+'.join(r['filters']) or '—'} | {_fmt(r['ate_rmse'])} | "
            f"{_fmt(r['ate_mean'])} | {_fmt(r['ate_median'])} | {_fmt(r['ate_std'])} | "
            f"{100 * r['tracked_fraction']:.0f}% | {r['fps']:.1f} | "
            f"{_fmt(r['segmentation_ms'], 1)} | {_fmt(r['mIoU'], 3)} | "
            f"{_fmt(r['person_IoU'], 3)} |"
        )
    return "\n".join(lines)


def _plots(out: Path, slam_dir: Path, sequence: Path, rows: list[dict[str, Any]]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from uss_slam.core.tum_io import read_trajectory
    from uss_slam.slam_eval import metrics

    fig, ax = plt.subplots(figsize=(7, 3.4))
    labels = [r["label"] for r in rows]
    values = [r["ate_rmse"] if r["ate_rmse"] is not None else 0.0 for r in rows]
    colors = ["0.5", "tab:green", "tab:orange", "tab:blue", "tab:purple"][: len(rows)]
    bars = ax.bar(range(len(rows)), [100 * v for v in values], color=colors)
    for bar, r in zip(bars, rows, strict=True):
        text = "n/a" if r["ate_rmse"] is None else f"{100 * r['ate_rmse']:.2f}"
        ax.text(bar.get_x() + bar.get_width() / 2, bar.get_height(), text, ha="center",
                va="bottom", fontsize=8)  # fmt: skip
    ax.set_xticks(range(len(rows)), labels, rotation=15, fontsize=8)
    ax.set_ylabel("ATE RMSE [cm]")
    ax.set_title(f"{sequence.name}: absolute trajectory error per variant")
    fig.tight_layout()
    fig.savefig(out / "ate_rmse.png", dpi=110)
    plt.close(fig)

    gt = read_trajectory(sequence / "groundtruth.txt")
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    axes = None
    for r, color in zip(rows, colors, strict=True):
        est = read_trajectory(slam_dir / r["variant"] / "trajectory.txt")
        try:
            result = metrics.ate(gt, est)
        except UssSlamError:
            continue
        if axes is None:
            spread = result.gt_positions.max(0) - result.gt_positions.min(0)
            axes = np.sort(np.argsort(-spread)[:2])
            ax.plot(*result.gt_positions[:, axes].T, "k--", lw=1.5, label="ground truth")
        ax.plot(*result.est_positions[:, axes].T, "-", color=color, lw=1.0, label=r["label"])
    if axes is not None:
        ax.set_xlabel(f"{'xyz'[axes[0]]} [m]")
        ax.set_ylabel(f"{'xyz'[axes[1]]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{sequence.name}: aligned trajectories (top view)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "trajectories.png", dpi=110)
    plt.close(fig)
    return ["ate_rmse.png", "trajectories.png"]


def stage_report(
    out: Path, plan: Plan, sequence: Path, times: dict[str, float], train_dirs: dict[str, Path]
) -> str:
    slam_dir = out / "slam"
    miou_file = out / "miou.json"
    miou = json.loads(miou_file.read_text())["scores"] if miou_file.is_file() else {}
    rows = summary_rows(slam_dir, miou)
    table = markdown_table(rows)
    plots = _plots(out, slam_dir, sequence, rows)
    from uss_slam.slam_eval.report import write_comparison

    runs = {v.name: json.loads((slam_dir / v.name / "metrics.json").read_text()) for v in VARIANTS}
    write_comparison(slam_dir, runs)
    val = {name: checkpoint_miou(best_checkpoint(d)) for name, d in train_dirs.items()}
    summary = {
        "experiment": plan.experiment,
        "sequence": str(sequence),
        "rows": rows,
        "val_mIoU": val,
        "stage_seconds": times,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    lines = [
        f"# uss-slam demo: {sequence.name} (experiment `{plan.experiment}`)",
        "",
        "Synthetic data (`data/`), two trainings of the same segmenter — with adversarial "
        "adaptation and source-only — (`train/`), their ONNX exports (`exports/`), and the SLAM "
        "harness on the target-style walking sequence with five dynamic-point treatments "
        "(`slam/<variant>/`, each with its own report).",
        "",
        table,
        "",
        f"ATE after SE(3) alignment; frames/s end to end; segmentation wall time per segmented "
        f"frame (in the prefetch threads); mIoU / person IoU of each segmenter on every "
        f"{plan.miou_stride}th frame of the SLAM sequence's labels (oracle = 1 by definition).",
        "",
        "Target validation mIoU (`val/mIoU` of the exported best checkpoint, in its name): "
        + ", ".join(f"{n} {_fmt(v, 3)}" for n, v in val.items())
        + ".",
        "",
        "Baseline-vs-each improvements: [slam/comparison.md](slam/comparison.md).",
        "",
        "![ATE RMSE per variant](ate_rmse.png)",
        "",
        "![aligned trajectories](trajectories.png)",
        "",
        "## Each run",
        "",
    ]
    for v in VARIANTS:
        lines += [
            f"### {v.label}",
            "",
            f"[report](slam/{v.name}/report.md)",
            "",
            f"![trajectory](slam/{v.name}/trajectory.png) ![ATE](slam/{v.name}/ate.png)",
            "",
        ]
    lines += [
        "## Time per stage",
        "",
        "| stage | seconds |",
        "|---|---|",
        *(f"| {name} | {seconds:.1f} |" for name, seconds in times.items()),
        "",
    ]
    (out / "report.md").write_text("\n".join(lines))
    print()
    print(table)
    print()
    return f"{out / 'report.md'} ({len(plots)} plots)"


# ------------------------------------------------------------------------------- main


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uss-demo",
        description="The end-to-end demo on synthetic data: generate data, train with adaptation "
        "and source-only, export both to ONNX, run the SLAM harness with five variants (no "
        "filter, oracle labels, source-only ONNX, adapted ONNX, adapted ONNX + geometry), print "
        "one table and write OUT/report.md. Complete stages with the same inputs are reused.",
    )
    parser.add_argument("--out", type=Path, default=Path("outputs/demo"),
                        help="output folder (default: outputs/demo)")  # fmt: skip
    parser.add_argument("--experiment", choices=sorted(PLANS), default="demo",
                        help="demo (default; minutes) or ci (tiny data, seconds of training)")  # fmt: skip
    parser.add_argument("--sequence", default="walking_xyz",
                        help="SLAM sequence: a name under OUT/data/slam/ (walking_xyz, "
                             "static_xyz) or a TUM RGB-D folder with labels/ (default: "
                             "walking_xyz)")  # fmt: skip
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--reuse", dest="force", action="store_false",
                       help="reuse stages already complete with the same inputs (default)")  # fmt: skip
    group.add_argument("--force", dest="force", action="store_true",
                       help="redo every stage")  # fmt: skip
    parser.set_defaults(force=False)  # (store_false would make --reuse's default True)
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--train-threads", type=int, default=None, metavar="N",
                        help="torch threads of the two trainings (default: the experiment's "
                             "num_threads, 2 for demo; 1 is faster on a busy shared machine)")  # fmt: skip
    return parser


def run_demo(
    out: Path, experiment: str = "demo", sequence: str = "walking_xyz", *,
    force: bool = False, quiet: bool = False, train_threads: int | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Run every stage (see the module doc); returns the content of ``OUT/summary.json``."""
    plan = PLANS[experiment]
    out = Path(out)
    if train_threads is not None and train_threads < 1:
        raise UssSlamError(f"--train-threads must be >= 1, got {train_threads}")
    data = out / "data"
    from uss_slam.synthetic.cli import DEMO_SLAM_PRESETS

    if not Path(sequence).is_dir() and sequence not in DEMO_SLAM_PRESETS:
        raise UssSlamError(
            f"--sequence {sequence}: not a folder, nor one of the demo's SLAM sequences "
            f"({', '.join(DEMO_SLAM_PRESETS)}, under {data / 'slam'})"
        )
    progress = Progress(total=1 + 2 * len(TRAININGS) + 1 + len(VARIANTS) + 1)
    progress.run("data", f"data: uss-synth demo --out {data}",
                 lambda: stage_data(data, plan, force, quiet))  # fmt: skip
    seq_path = Path(sequence) if Path(sequence).is_dir() else data / "slam" / sequence
    if not (seq_path / "rgb.txt").is_file():
        raise UssSlamError(
            f"--sequence {sequence}: {seq_path} is not a TUM RGB-D folder (no rgb.txt); use "
            f"a name under {data / 'slam'} or a sequence folder"
        )
    data_key = _data_key(data)
    train_dirs = {name: out / "train" / name for name in TRAININGS}
    for name, run_dir in train_dirs.items():
        overrides = train_overrides(plan, data, name, train_threads)
        progress.run("train", f"train {name}: uss-train {' '.join(overrides)}",
                     lambda o=overrides, d=run_dir: stage_train(d, o, data_key, force))  # fmt: skip
    models = {name: out / "exports" / f"{name}.onnx" for name in TRAININGS}
    for name, model in models.items():
        progress.run("export", f"export {name} -> {model}",
                     lambda d=train_dirs[name], m=model: stage_export(d, m, force))  # fmt: skip
    progress.run("miou", f"mIoU on {seq_path.name}",
                 lambda: stage_miou(out, seq_path, models, plan.miou_stride, force))  # fmt: skip
    inputs = {name: file_sha256(model) for name, model in models.items()}
    inputs["sequence"] = data_key if seq_path.parent == data / "slam" else str(seq_path)
    for v in VARIANTS:
        overrides = slam_overrides(v, seq_path, models)
        used = {k: inputs[k] for k in ("sequence", v.segmenter) if k in inputs}
        progress.run("slam", f"slam {v.name}: uss-slam {' '.join(overrides)}",
                     lambda v=v, o=overrides, u=used: stage_slam(
                         out / "slam" / v.name, o, u, force, quiet))  # fmt: skip
    progress.run("report", "report",
                 lambda: stage_report(out, plan, seq_path, progress.times, train_dirs))  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    total = time.perf_counter() - progress.start
    print(f"uss-demo: done in {total:.1f} s; report: {out / 'report.md'}")
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        run_demo(args.out, args.experiment, args.sequence, force=args.force, quiet=args.quiet,
                 train_threads=args.train_threads)  # fmt: skip
    except UssSlamError as error:
        print(f"uss-demo: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""``uss-eval compare MODEL MODEL [...] --sequence DIR [...]``: the command line and
:func:`compare` (check everything, run, write the report, print the table and the verdict)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from uss_slam.core.arguments import THREADS_ARG, Names, given_once, number, path_argument
from uss_slam.core.classes import CLASS_NAMES, DYNAMIC_CLASSES
from uss_slam.core.cli import exit_on_user_error, warning
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import check_output_owner, check_writable, output_lock
from uss_slam.core.paths import input_file, input_folder, output_folder
from uss_slam.core.validators import NEEDS_SOURCE, build_validators

from . import compare_report
from .compare import (
    ComparePlan,
    attach_labels,
    check_models,
    check_sequences,
    run_compare,
    source_images,
)
from .compare_slam import SlamPlan, check_slam, run_slam_rows, slam_markdown
from .frames import CONFIG_DIR

PROG = "uss-eval"
COMMAND = "uss-eval compare"
VALIDATORS_CONFIG = CONFIG_DIR / "validators" / "default.yaml"
MAX_BATCH = 256
"""Largest ``--batch``: frames per inference, held in memory at once (as ``slam.prefetch``)."""


SOURCE_FRAMES = 32
"""Source images used with ``--source`` when ``--source-frames`` is not given."""
SLAM_REPEATS = 3
"""SLAM runs per row with ``--slam`` when ``--repeats`` is not given."""


def default_validators() -> tuple[list[str], dict[str, Any]]:
    """The ``validators`` config group's default: ``(names, params)``."""
    cfg = yaml.safe_load(VALIDATORS_CONFIG.read_text(encoding="utf-8"))
    return list(cfg["names"]), dict(cfg.get("params") or {})


def plan_compare(
    models: Sequence[Path],
    sequences: Sequence[Path],
    *,
    stride: int = 1,
    labels: Sequence[Path] = (),
    label_frames: int | None = None,
    source: Path | None = None,
    source_frames: int | None = None,
    validators: Sequence[str] | None = None,
    dynamic: Sequence[str] = DYNAMIC_CLASSES,
    batch: int = 4,
    threads: int | None = None,
) -> ComparePlan:
    """Every input checked (models, frames' headers, labels read and checked, source images),
    no inference yet: a bad input is one line naming the file or option."""
    for key, value in (("--batch", batch), ("--source-frames", source_frames)):
        if value is not None and value < 1:
            raise UssSlamError(f"{key}: expected an integer >= 1, got {value}")
    if label_frames is not None and label_frames < 1:
        raise UssSlamError(f"--label-frames: expected an integer >= 1, got {label_frames}")
    if label_frames is not None and not labels:
        raise UssSlamError("--label-frames needs --labels FOLDER (label PNGs named as the frames)")
    if source_frames is not None and source is None:
        raise UssSlamError("--source-frames needs --source DIR (the source-domain images)")
    unknown = [c for c in dynamic if c not in CLASS_NAMES]
    if unknown or not dynamic:
        raise UssSlamError(
            f"--dynamic {','.join(dynamic)}: expected class names of {', '.join(CLASS_NAMES)}"
        )
    names, params = default_validators()
    if validators is not None:
        names = list(validators)
    build_validators(names, params, "--validators")  # unknown names: one line
    if source is None and NEEDS_SOURCE & set(names):
        if validators is not None:
            raise UssSlamError(
                f"--validators {','.join(sorted(NEEDS_SOURCE & set(names)))}: needs --source FOLDER (source images)"
            )
        names = [n for n in names if n not in NEEDS_SOURCE]
    checked = check_models(models, dynamic, threads)
    frames, seq_names = check_sequences(sequences, stride)
    if labels:
        attach_labels(frames, labels, label_frames, len(CLASS_NAMES))
    src = source_images(source, source_frames or SOURCE_FRAMES) if source is not None else []
    return ComparePlan(checked, frames, seq_names, tuple(dynamic), names, params, src, batch)


def compare(
    plan: ComparePlan,
    out: Path,
    quiet: bool = False,
    slam: SlamPlan | None = None,
    tables: bool = True,
) -> dict[str, Any]:
    """Run ``plan`` (and ``slam``'s SLAM rows), write the report into ``out``, print the table
    (``tables``), the findings and the verdict; returns ``compare.json``."""
    progress = None
    if not quiet and sys.stderr.isatty():

        def progress(done: int, total: int) -> None:
            print(f"\r{COMMAND}: {done}/{total} frames", end="" if done < total else "\n",
                  file=sys.stderr, flush=True)  # fmt: skip

    with output_lock(out, "--out"):
        result = run_compare(plan, progress)
        stats = compare_report.intervals(result)
        lines, last = compare_report.verdict(result, stats)
        note = compare_report.small_label_warning(result, stats)
        if note:
            warning(note)
        extra, data = "", {}
        if slam is not None:
            rows = run_slam_rows(plan, slam, out)
            extra, slam_findings = slam_markdown(rows, slam.static)
            lines += slam_findings
            data = {"slam": rows, "static": list(slam.static), "repeats": slam.repeats}
        compare_report.write_report(out, result, stats, lines, last, extra, data)
    if tables:
        print(compare_report.table(result, stats))
        if extra:
            print(extra)
    for line in lines:
        print(line)
    print(f"{COMMAND}: {len(plan.models)} models x {len(plan.frames)} frames in "
          f"{result.seconds:.1f} s; wrote {out / 'report.md'}")  # fmt: skip
    print(last)
    return compare_report.summary(result, stats, lines, last)


def check_out(out: Path, inputs: Sequence[tuple[str, Path]] = ()) -> None:
    output_folder(out, "--out", inputs=inputs)
    check_writable(out, "--out", create=False)
    check_output_owner(out, PROG, "--out")


def check_paths(args: argparse.Namespace) -> None:
    """Every input path through the path layer (:mod:`uss_slam.core.paths`) before anything
    is read: a missing file, a loop, a dangling link, a name too long is one line naming it."""
    for model in args.models:
        input_file(model, None, "expected an exported model (.onnx file written by uss-export)")
    for key, folders in (("--sequence", args.sequence), ("--labels", args.labels),
                         ("--source", [args.source] if args.source else [])):  # fmt: skip
        for folder in folders:
            input_folder(folder, key)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=COMMAND,
        description="Did adaptation help on my target? Compare two or more exported models on "
        "unlabelled target frames: label-free validators per model, dynamic-mask agreement per "
        "pair, a contact sheet of the frames where they disagree most; with --labels, person "
        "IoU and mIoU with bootstrap intervals and a verdict. Writes OUT/report.md, "
        "OUT/compare.json and images; prints the table; the last line says what to do.",
    )
    parser.add_argument(
        "models",
        nargs="+",
        type=path_argument,
        metavar="MODEL",
        help="exported .onnx models (2 or more)",
    )
    parser.add_argument("--sequence", type=path_argument, action="append", default=[], metavar="DIR",
                        help="a TUM RGB-D folder (rgb.txt, rgb/) of target frames; repeatable")  # fmt: skip
    parser.add_argument(
        "--stride", type=number(int, min=1), default=1, help="every N-th frame (default: 1)"
    )
    parser.add_argument("--labels", type=path_argument, action="append", default=[], metavar="DIR",
                        help="a folder of uint8 class-id PNGs named as colour frames (a "
                             "sequence's labels/); repeatable")  # fmt: skip
    parser.add_argument("--label-frames", type=number(int, min=1), default=None, metavar="N",
                        help="use N labelled frames, evenly spaced (default: every one found)")  # fmt: skip
    parser.add_argument("--source", type=path_argument, default=None, metavar="DIR",
                        help="source-domain images (PNG/JPEG, e.g. VOC's JPEGImages): adds the "
                             "domain-separability probe")  # fmt: skip
    parser.add_argument(
        "--source-frames",
        type=number(int, min=1),
        default=None,
        help=f"source images used, with --source (default: {SOURCE_FRAMES})",
    )
    parser.add_argument("--validators", default=None,
                        help="comma-separated validators (default: configs/validators/default.yaml)")  # fmt: skip
    parser.add_argument("--dynamic", type=Names(CLASS_NAMES), default=",".join(DYNAMIC_CLASSES),
                        help=f"classes of the dynamic mask (default: {','.join(DYNAMIC_CLASSES)})")  # fmt: skip
    parser.add_argument("--out", type=path_argument, default=None,
                        help="report folder (default: outputs/compare/<model stems>)")  # fmt: skip
    parser.add_argument("--slam", action="store_true",
                        help="also run the SLAM harness on each sequence: no filter and each "
                             "model's semantic filter, --repeats runs per row")  # fmt: skip
    parser.add_argument(
        "--repeats",
        type=number(int, "a range needs two runs", min=2),
        default=None,
        help=f"SLAM runs per row, with --slam: at least 2, the report gives each row's range "
        f"(default: {SLAM_REPEATS})",
    )
    parser.add_argument("--static", action="append", default=[], metavar="NAME",
                        help="a compared sequence (folder name) in which nothing moves: the "
                             "report gives each filter's cost there (with --slam; repeatable)")  # fmt: skip
    parser.add_argument(
        "--batch",
        type=number(int, "frames held in memory at once", min=1, max=MAX_BATCH),
        default=4,
        help="frames per inference (default: 4)",
    )
    parser.add_argument(
        "--threads", type=THREADS_ARG, default=None, help="inference threads (default: all)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    return given_once(parser)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    out = args.out or Path("outputs") / "compare" / "_vs_".join(m.stem for m in args.models)
    with exit_on_user_error(COMMAND):
        check_paths(args)
        check_out(out, [*(("--sequence", s) for s in args.sequence),
                        *(("--labels", f) for f in args.labels),
                        *([("--source", args.source)] if args.source else [])])  # fmt: skip
        plan = plan_compare(
            args.models, args.sequence, stride=args.stride, labels=args.labels,
            label_frames=args.label_frames, source=args.source, source_frames=args.source_frames,
            validators=None if args.validators is None else [v.strip() for v in args.validators.split(",") if v.strip()],
            dynamic=args.dynamic,
            batch=args.batch, threads=args.threads,
        )  # fmt: skip
        if args.static and not args.slam:
            raise UssSlamError(
                "--static needs --slam (it names where a filter's SLAM cost is measured)"
            )
        if args.repeats is not None and not args.slam:
            raise UssSlamError("--repeats needs --slam (it counts the SLAM runs per row)")
        repeats = args.repeats or SLAM_REPEATS
        slam = check_slam(plan, args.sequence, args.static, repeats) if args.slam else None
        compare(plan, out, quiet=args.quiet, slam=slam)
    return 0

"""``uss-traj``: ATE / RPE of a TUM-format trajectory against ground truth (evo-compatible numbers).

Exit codes: 0 success, 1 bad input file (one line on stderr naming the file and line), 2 bad
arguments (argparse).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from uss_slam.core.arguments import given_once, number, path_argument
from uss_slam.core.cli import interruptible, print_output, report_interrupt
from uss_slam.core.errors import UssSlamError
from uss_slam.core.paths import input_file, naming, output_file
from uss_slam.core.tum_io import read_trajectory

from .metrics import (
    ALIGNMENTS,
    DEFAULT_MAX_DIFF,
    DELTA_UNITS,
    AteResult,
    ErrorStats,
    NoPairsError,
    RpeResult,
    ate,
    ate_bands,
    rpe,
)
from .plots import check_plot_path, plot_ate

PROG = "uss-traj"
_STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max")
_ALIGN_TITLES = {
    "se3": "SE(3) Umeyama alignment",
    "sim3": "Sim(3) Umeyama alignment",
    "none": "not aligned",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=(
            "Trajectory error of an estimate against ground truth, both TUM files "
            "('timestamp tx ty tz qx qy qz qw'). Poses are associated by nearest timestamp "
            "as evo does; numbers agree with evo_ape / evo_rpe for the same settings."
        ),
        epilog="Exit codes: 0 ok, 1 bad input file, 2 bad arguments.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="{ate,rpe}")
    _ate_parser(sub)
    _rpe_parser(sub)
    return given_once(parser)


def _common_arguments(p: argparse.ArgumentParser) -> None:
    """The files, the association and the output format, shared by ``ate`` and ``rpe``."""
    p.add_argument(
        "gt", type=path_argument, metavar="GT", help="ground-truth trajectory (TUM format)"
    )
    p.add_argument(
        "est", type=path_argument, metavar="EST", help="estimated trajectory (TUM format)"
    )
    p.add_argument(
        "--max-diff",
        type=number(float, min=0),
        default=DEFAULT_MAX_DIFF,
        metavar="S",
        help="largest stamp difference of an associated pair, seconds, inclusive "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--offset",
        type=number(float),
        default=0.0,
        metavar="S",
        help="seconds added to EST's stamps before association (default: %(default)s)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")


def _ate_parser(sub: Any) -> None:
    p_ate = sub.add_parser(
        "ate",
        help="absolute trajectory error (translation, metres)",
        description="Absolute trajectory error: distance between aligned estimated and "
        "ground-truth positions (evo_ape, translation part).",
    )
    _common_arguments(p_ate)
    p_ate.add_argument(
        "--align",
        choices=ALIGNMENTS,
        default="se3",
        help="Umeyama alignment of EST onto GT: se3 (rigid, evo --align), sim3 (with scale, "
        "evo --align --correct_scale) or none (default: %(default)s)",
    )
    p_ate.add_argument(
        "--bands",
        type=number(float, gt=0),
        metavar="S",
        help="also split the error into its slow part (the aligned error vectors averaged over "
        "S seconds around each pose: drift and bias a keyframe back end can correct) and its "
        "fast part (the rest: per-frame jitter), e.g. --bands 0.5",
    )
    p_ate.add_argument(
        "--plot",
        type=path_argument,
        metavar="FILE",
        help="also save a figure: top view of both trajectories and the error over time "
        "(format from the extension: .png, .pdf, .svg, ...)",
    )
    p_ate.set_defaults(subparser=p_ate)


def _rpe_parser(sub: Any) -> None:
    p_rpe = sub.add_parser(
        "rpe",
        help="relative pose error (translation metres, rotation degrees)",
        description="Relative pose error over pose pairs DELTA apart among the associated "
        "poses (evo_rpe, consecutive pairs). frames: pairs (0,d),(d,2d),... as evo "
        "--delta_unit f; seconds: every pose paired with the one nearest DELTA seconds later, "
        "as TUM's evaluate_rpe.py --fixed_delta (pairs across gaps are skipped and counted).",
    )
    _common_arguments(p_rpe)
    p_rpe.add_argument(
        "--delta",
        type=number(float, gt=0),
        default=1.0,
        metavar="D",
        help="pair distance in --unit (default: %(default)s)",
    )
    p_rpe.add_argument(
        "--unit", choices=DELTA_UNITS, default="frames", help="unit of --delta (default: frames)"
    )
    p_rpe.set_defaults(subparser=p_rpe)  # so that checks after parsing print this usage


def _stats_lines(stats: ErrorStats, unit: str) -> list[str]:
    return [f"{key:>8}  {getattr(stats, key):.6f} {unit}" for key in _STAT_KEYS]


def format_ate(result: AteResult, gt: Path, est: Path, max_diff: float, offset: float) -> str:
    """A small evo-like table of ATE statistics."""
    lines = [
        f"ATE w.r.t. translation (m), {_ALIGN_TITLES[result.align]}",
        f"ground truth: {gt}",
        f"estimate:     {est}",
        f"associated:   {result.stats.pairs} pose pairs (max_diff {max_diff:g} s, "
        f"offset {offset:g} s)",
    ]
    if result.align == "sim3":
        lines.append(f"scale:        {result.scale:.6f}")
    lines.append("")
    lines += _stats_lines(result.stats, "m")
    return "\n".join(lines)


def format_rpe(result: RpeResult, gt: Path, est: Path, max_diff: float, offset: float) -> str:
    """A small evo-like table of RPE statistics: translation (m) and rotation (deg) columns."""
    skipped = f", {result.skipped} skipped across gaps" if result.unit == "seconds" else ""
    lines = [
        f"RPE for delta = {result.delta:g} {result.unit}",
        f"ground truth: {gt}",
        f"estimate:     {est}",
        f"pairs:        {result.pairs}{skipped} (association max_diff {max_diff:g} s, "
        f"offset {offset:g} s)",
        "",
        f"{'':>8}  {'trans (m)':>12}  {'rot (deg)':>12}",
    ]
    for key in _STAT_KEYS:
        lines.append(
            f"{key:>8}  {getattr(result.trans, key):12.6f}  {getattr(result.rot_deg, key):12.6f}"
        )
    return "\n".join(lines)


@interruptible  # SIGTERM as Ctrl-C
def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "rpe" and args.unit == "frames" and not float(args.delta).is_integer():
        args.subparser.error(f"--delta must be a whole number of frames, got {args.delta:g}")
    try:
        for path in (args.gt, args.est):
            input_file(path, None, "expected a trajectory file (TUM format)")
        if args.command == "ate" and args.plot is not None:  # before any work
            inputs = [(None, args.gt), (None, args.est)]
            output_file(args.plot, "--plot", "expected an image file name", inputs=inputs)
            check_plot_path(args.plot, "--plot")
        gt = read_trajectory(args.gt)
        est = read_trajectory(args.est)
        if args.command == "ate":
            result = ate(gt, est, max_diff=args.max_diff, offset=args.offset, align=args.align)
            bands = None if args.bands is None else ate_bands(result, args.bands)
            if args.json:
                data = result.as_dict()
                if bands is not None:
                    data["bands"] = bands.as_dict()
                out = json.dumps(data)
            else:
                out = format_ate(result, args.gt, args.est, args.max_diff, args.offset)
                if bands is not None:
                    out += (
                        f"\n\n{'slow':>8}  {bands.slow:.6f} m  (RMSE of the error averaged over "
                        f"{bands.window:g} s)\n{'fast':>8}  {bands.fast:.6f} m  (RMSE of the rest)"
                    )
            if args.plot is not None:
                with naming("--plot", args.plot):  # a write that fails names its flag
                    plot_ate(args.plot, result)
        else:
            delta = int(args.delta) if args.unit == "frames" else args.delta
            try:
                result = rpe(
                    gt, est, delta=delta, unit=args.unit, max_diff=args.max_diff,
                    offset=args.offset,
                )  # fmt: skip
            except NoPairsError as error:  # the flag to change, then what was found
                raise UssSlamError(f"--delta={args.delta:g} ({args.unit}): {error}") from None
            out = (
                json.dumps(result.as_dict())
                if args.json
                else format_rpe(result, args.gt, args.est, args.max_diff, args.offset)
            )
    except UssSlamError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as interrupt:  # Ctrl-C or SIGTERM
        # the plot is written atomically: nothing half-written is left
        return report_interrupt(PROG, interrupt)
    return print_output(out)  # a closed pipe (| head -c0): exit code 1, nothing on stderr


if __name__ == "__main__":
    sys.exit(main())

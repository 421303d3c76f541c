"""``uss-vocab``: build a small DBoW2 ORB vocabulary for ORB-SLAM3 from TUM sequence frames, or
check one.

Exit codes: 0 success, 1 bad input (one line on stderr naming the file or option), 2 bad
arguments (argparse).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from uss_slam.core.arguments import given_once, number, path_argument
from uss_slam.core.cli import exit_code, interruptible, print_output, report_interrupt
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import output_lock
from uss_slam.core.paths import distinct_folders, input_file, input_folder, naming, output_file
from uss_slam.core.ranges import MAX_FEATURES, MAX_SEED

from .vocabulary import (
    MAX_BRANCHING,
    MAX_LEVELS,
    build_from_sequences,
    read_header,
    read_vocabulary,
)

PROG = "uss-vocab"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="DBoW2 ORB vocabularies for `uss-slam system=orbslam3 system.vocabulary=FILE`.",
        epilog="Exit codes: 0 ok, 1 bad input, 2 bad arguments.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="{build,info}")
    build = sub.add_parser(
        "build",
        help="cluster the ORB descriptors of sequence frames into a vocabulary tree",
        description="Extract ORB descriptors (ORB-SLAM's settings: 1000 features, scale 1.2, "
        "8 levels) from the rgb.txt frames of TUM sequence folders, cluster them into a tree "
        "of branching K and depth L by hierarchical k-majority (DBoW2's k-medians for binary "
        "descriptors), weight the words by TF-IDF and write DBoW2's text format "
        "(ORB-SLAM3's loadFromTextFile). Deterministic for a --seed.",
    )
    build.add_argument("sequences", nargs="+", type=path_argument, metavar="SEQUENCE_DIR")
    build.add_argument(
        "--out", type=path_argument, required=True, metavar="FILE", help="vocabulary file"
    )
    build.add_argument(
        "-k",
        "--branching",
        type=number(int, min=2, max=MAX_BRANCHING),
        default=10,
        metavar="K",
        help=f"children per node, 2..{MAX_BRANCHING} (default: %(default)s)",
    )
    build.add_argument(
        "-L",
        "--levels",
        type=number(int, min=1, max=MAX_LEVELS),
        default=4,
        metavar="L",
        help=f"tree depth, 1..{MAX_LEVELS}: up to K^L words (default: %(default)s)",
    )
    build.add_argument(
        "--stride",
        type=number(int, min=1),
        default=5,
        metavar="N",
        help="use every N-th listed frame of each sequence (default: %(default)s)",
    )
    build.add_argument(
        "--max-frames",
        type=number(int, min=1),
        default=None,
        metavar="N",
        help="at most N frames per sequence (default: all)",
    )
    build.add_argument(
        "--features",
        type=number(int, min=1, max=MAX_FEATURES),
        default=1000,
        metavar="N",
        help="ORB features per frame (default: %(default)s)",
    )
    build.add_argument("--seed", type=number(int, min=0, max=MAX_SEED), default=0,
                       help="random seed (default: %(default)s)")  # fmt: skip
    build.add_argument(
        "--max-iterations",
        type=number(int, min=1),
        default=100,
        metavar="N",
        help="cap of k-majority iterations per node (default: %(default)s)",
    )
    build.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    info = sub.add_parser(
        "info",
        help="read and check a DBoW2 text vocabulary, print k, L and its size",
        description="Read a DBoW2 text vocabulary (this tool's or ORB-SLAM's ORBvoc.txt), "
        "check every line, and print its parameters and size.",
    )
    info.add_argument("vocabulary", type=path_argument, metavar="FILE")
    return given_once(parser)


@interruptible  # SIGTERM as Ctrl-C
def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "build":
            for folder in args.sequences:
                input_folder(folder, None, "expected a TUM sequence with rgb.txt")
            args.sequences = distinct_folders(args.sequences, None)  # each once
            output_file(args.out, "--out", "expected a vocabulary file")  # before the lock
            # a second build into the same file stops at once (exit code 2), naming the first
            with output_lock(args.out, "--out"), naming("--out", args.out):
                _build(args)
        else:
            input_file(args.vocabulary, None, "expected a DBoW2 text vocabulary file")
            vocab = read_vocabulary(args.vocabulary)
            return print_output(  # its product: stdout that fails is its error
                f"{args.vocabulary}: k={vocab.k} L={vocab.levels} scoring={vocab.scoring} "
                f"weighting={vocab.weighting}, {vocab.n_nodes} nodes, {vocab.n_words} words"
            )
    except UssSlamError as err:
        print(f"{PROG}: error: {err}", file=sys.stderr)
        return exit_code(err)
    except KeyboardInterrupt as interrupt:  # Ctrl-C or SIGTERM
        # --out is written atomically: nothing half-written is left
        return report_interrupt(PROG, interrupt)
    return 0


def _build(args: argparse.Namespace) -> None:
    """``uss-vocab build``: the checks of ``--out``, the clustering, the summary line."""
    if args.out.exists() and not args.overwrite:
        raise UssSlamError(f"--out={args.out}: exists; pass --overwrite to replace it")
    if args.out.exists():  # --overwrite replaces a vocabulary, never another file
        try:
            read_header(args.out)
        except UssSlamError:
            raise UssSlamError(
                f"--out={args.out}: not a DBoW2 text vocabulary; --overwrite replaces "
                "only a vocabulary file"
            ) from None
    report = build_from_sequences(
        args.sequences,
        args.out,
        k=args.branching,
        levels=args.levels,
        stride=args.stride,
        max_frames=args.max_frames,
        n_features=args.features,
        seed=args.seed,
        max_iterations=args.max_iterations,
    )
    print(
        f"wrote {report.path}: k={args.branching} L={args.levels}, {report.nodes} nodes, "
        f"{report.words} words ({report.zero_weight_words} with weight 0) from "
        f"{report.descriptors} descriptors of {report.images} frames "
        f"(extraction {report.extract_s:.1f} s, clustering {report.cluster_s:.1f} s)"
    )
    if report.zero_weight_words == report.words:
        # idf = ln(N / N_i) is 0 for a word in every training frame: such a vocabulary
        # scores every pair of frames alike (no place recognition, no relocalisation).
        where = ", ".join(str(folder) for folder in args.sequences)
        print(
            f"{PROG}: warning: {where}: every word of the vocabulary has weight 0 (each "
            f"occurs in all {report.images} training frames); use more, and more "
            "varied, frames (--stride, --max-frames, more sequences)",
            file=sys.stderr,
        )


if __name__ == "__main__":
    sys.exit(main())

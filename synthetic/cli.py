"""``uss-synth``: render synthetic TUM RGB-D sequences and VOC-layout segmentation sets."""

from __future__ import annotations

import argparse
import sys
import textwrap
import time
from collections.abc import Sequence

import cv2

from uss_slam.core.arguments import given_once, number, path_argument
from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.cli import program, report_interrupt, signals_as_interrupts
from uss_slam.core.errors import UssSlamError
from uss_slam.core.paths import output_folder
from uss_slam.core.ranges import MAX_SEED
from uss_slam.core.resources import check_memory

from .motion import PRESETS
from .output import (
    OUTPUT_MARKER,
    SynthArgumentError,
    check_output,
    clean_stale_partials,
    parse_size,
)
from .sequence import READOUT, SEQUENCE_OUTFITS, TIMINGS, render_sequence
from .styles import STYLES
from .textures import WARDROBES
from .voc import render_voc, render_voc_frames


class _Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments on one line with exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _size(text: str) -> tuple[int, int]:
    try:
        return parse_size(text)
    except SynthArgumentError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


MAX_FRAMES = 18_000
"""Largest ``--frames``: 10 minutes at 30 Hz, longer than any TUM RGB-D sequence (a few
minutes at most); at 640x480 a frame takes about 1.1 MB on disk (RGB, depth, labels), so
this is already about 20 GB."""
MAX_IMAGES = 100_000
"""Largest ``--images``: more than VOC, SBD and COCO's person / chair / monitor images
together; at 320x240 an image with its label takes about 32 KB on disk (3 GB in all)."""


def _preset(text: str) -> str:
    if text not in PRESETS:
        raise argparse.ArgumentTypeError(
            f"unknown preset {text!r}; choose one of {', '.join(PRESETS)}"
        )
    return text


def _wrap(text: str) -> str:
    return textwrap.fill(text, width=90)


def build_parser() -> argparse.ArgumentParser:
    presets = "\n".join(f"  {p.name:<19} {p.description}" for p in PRESETS.values())
    parser = _Parser(
        prog="uss-synth",
        description=_wrap(
            "Render deterministic synthetic RGB-D data: TUM RGB-D sequences with ground truth "
            "and per-pixel labels, and PASCAL VOC 2012-layout segmentation sets. Same "
            "arguments => byte-identical files. Output folders appear only when complete; "
            "partial folders of killed runs are removed by the next run; --overwrite replaces "
            f"only uss-synth outputs (folders with {OUTPUT_MARKER} or synthetic.yaml)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"sequence presets:\n{presets}",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="{sequence,voc}")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--seed", type=number(int, min=0, max=MAX_SEED), default=0,
                       help="random seed (default: 0)")  # fmt: skip
        p.add_argument(
            "--out", type=path_argument, required=True, help="output folder (must be new or empty)"
        )
        p.add_argument(
            "--overwrite",
            action="store_true",
            help="replace a non-empty output folder of uss-synth (only after rendering "
            "succeeded; any other folder is refused)",
        )
        p.add_argument("--quiet", action="store_true", help="no progress bar")  # fmt: skip

    def size(p: argparse.ArgumentParser, default: tuple[int, int]) -> None:
        p.add_argument(
            "--size",
            type=_size,
            default=default,
            metavar="WxH",
            help=f"image size (default: {default[0]}x{default[1]})",
        )

    seq = sub.add_parser(
        "sequence",
        help="a TUM RGB-D sequence (rgb/, depth/, labels/, rgb.txt, depth.txt, groundtruth.txt)",
        description=_wrap(
            "Render a TUM RGB-D sequence folder: rgb/ (PNG), depth/ (uint16 PNG, 5000 = 1 m, "
            "0 = no data, beyond 4.5 m dropped), labels/ (uint8 class ids: "
            + ", ".join(f"{i} {n}" for i, n in enumerate(CLASS_NAMES))
            + "), rgb.txt, depth.txt, groundtruth.txt (100 Hz, camera-to-world, optical frame), "
            "intrinsics.yaml (TUM fr3 scaled to --size) and synthetic.yaml (the arguments)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"presets:\n{presets}",
    )
    seq.add_argument(
        "--preset",
        type=_preset,
        required=True,
        metavar="NAME",
        help=f"camera motion and people ({', '.join(PRESETS)})",
    )
    seq.add_argument(
        "--frames",
        type=number(
            int,
            "10 minutes at 30 Hz; about 1.1 MB per 640x480 frame on disk: 20 GB",
            min=2,
            max=MAX_FRAMES,
        ),
        default=120,
        help=f"number of frames at 30 Hz (2..{MAX_FRAMES}, default: 120)",
    )
    size(seq, (640, 480))
    seq.add_argument("--style", choices=STYLES, default="target",
                     help="source: clean and evenly lit; target: Kinect-like blur, noise, colour "
                          "cast, depth noise and holes (default: target)")  # fmt: skip
    seq.add_argument("--outfits", choices=SEQUENCE_OUTFITS, default="office",
                     help="what the people wear: office = the style's outfits (the same in every "
                          "sequence of the style); drawn = outfits drawn for this sequence (seed, "
                          "preset) from the voc 'all' wardrobe's distribution (default: office)")  # fmt: skip
    seq.add_argument("--timing", choices=TIMINGS, default=None,
                     help="the target style's sensor timing: global = colour, labels and depth "
                          f"at the colour stamp; rolling = a rolling shutter ({READOUT * 1000:.0f} "
                          "ms readout, the labels skewed with the colour); misregistered = the "
                          "depth image at its own stamp; kinect = both (default: the preset's; "
                          "handheld_rpy, handheld_fast: kinect, the others: global)")  # fmt: skip
    common(seq)

    voc = sub.add_parser(
        "voc",
        help="a PASCAL VOC 2012-layout segmentation set (or its content in the target style)",
        description=_wrap(
            "Render OUT/VOCdevkit/VOC2012 with JPEGImages/ (JPEG quality 90), SegmentationClass/ "
            "(palette PNGs: person 15, chair 9, tvmonitor 20, 255 void band along outlines) and "
            "ImageSets/Segmentation/{train,val,trainval}.txt (every fifth image is val). Every "
            "image is a new random layout and viewpoint showing a person, chair or monitor."
        ),
    )
    voc.add_argument(
        "--images",
        type=number(int, "about 32 KB per 320x240 image on disk: 3 GB", min=1, max=MAX_IMAGES),
        default=200,
        help=f"number of images (1..{MAX_IMAGES}, default: 200)",
    )
    size(voc, (320, 240))
    voc.add_argument(
        "--outfits",
        choices=WARDROBES,
        default="classic",
        help="the people's clothing: classic = saturated stripes, checks and prints (12 outfits); "
        "varied = every kind of fabric and colour, a new wardrobe of 4 outfits every 20 images; "
        "all = every garment family of the world (the classic prints, the varied fabrics and "
        "the target's cloths) in rooms of both material families, a new wardrobe every 20 "
        "images (default: classic)",
    )
    voc.add_argument(
        "--near",
        type=number(float, min=0, max=1),
        default=0.0,
        metavar="SHARE",
        help="the share of images (0..1) that face a person at walking distance (0.6-1.6 m, "
        "camera at chest height), as the tum_like shift's source set (0.3) and real photos "
        "do; the other images are as with 0 (default: 0)",
    )
    voc.add_argument(
        "--style",
        choices=(*STYLES, "mixed"),
        default="source",
        help="source: the VOC tree; target: the same content in the recordings' lighting and "
        "sensor, written as a labelled image folder (rgb/, labels/ with the void band, "
        "rgb.txt; no depth), as the appearance shift's target frames; mixed: the VOC tree with "
        "each image in the source or the target style (even odds), as a broad photo "
        "collection such as COCO, the stand-in for a pretraining set (default: source)",
    )
    common(voc)

    return given_once(parser)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "sequence":
        preset = PRESETS[args.preset]
        if args.frames < preset.min_frames:
            parser.error(
                f"argument --frames: the {preset.name} preset needs at least "
                f"{preset.min_frames} frames ({preset.min_frames_reason}); got {args.frames}"
            )
        if args.timing is not None and args.style != "target":  # accepted, changes nothing
            print(f"uss-synth: warning: --timing applies to the target style's sensor only; "
                  f"ignored with --style {args.style}", file=sys.stderr)  # fmt: skip
    with program("uss-synth"), signals_as_interrupts():  # warnings: "uss-synth: warning: ..."
        return _render(args)


RENDER_BYTES_PER_PIXEL = 140
"""Memory one rendered frame takes per pixel (its float buffers, depth, labels, noise pool):
the peak RSS of ``uss-synth sequence --preset walking_xyz --frames 2 --size WxH`` grew by
518 MB from 1280x960 to 2560x1920 (382 -> 901 MB; AMD EPYC, ``/usr/bin/time -f %M``)."""


def check_frame_memory(size: tuple[int, int]) -> None:
    """One line before rendering when a frame of ``size`` (W, H) cannot fit in the memory left
    (:func:`~uss_slam.core.resources.check_memory`): 4096x4096 needs about 2.3 GB."""
    w, h = size
    check_memory(RENDER_BYTES_PER_PIXEL * w * h, f"--size={w}x{h}", "rendering a frame",
                 "--size")  # fmt: skip


def _render(args: argparse.Namespace) -> int:
    """:func:`main` once the arguments are parsed: render, every error as one line."""
    cv2.setNumThreads(1)
    start = time.perf_counter()
    try:
        output_folder(args.out, "--out")  # before rendering, not after
        check_output(args.out, args.overwrite)
        check_frame_memory(args.size)
        for folder in clean_stale_partials(args.out):
            print(f"uss-synth: removed {folder} (left by a killed run)", file=sys.stderr)
        if args.command == "sequence":
            out = render_sequence(args.out, preset=args.preset, frames=args.frames, size=args.size,
                                  seed=args.seed, style=args.style, outfits=args.outfits,
                                  timing=args.timing, overwrite=args.overwrite,
                                  progress=not args.quiet)  # fmt: skip
            print(f"wrote {args.frames} frames ({args.preset}, {args.style}, "
                  f"{args.size[0]}x{args.size[1]}) to {out}")  # fmt: skip
        elif args.style == "target":
            out = render_voc_frames(args.out, images=args.images, size=args.size, seed=args.seed,
                                    outfits=args.outfits, style="target", near=args.near,
                                    overwrite=args.overwrite, progress=not args.quiet)  # fmt: skip
            print(f"wrote {args.images} labelled target-style images "
                  f"({args.size[0]}x{args.size[1]}) to {out}")  # fmt: skip
        else:
            out = render_voc(args.out, images=args.images, size=args.size, seed=args.seed,
                             outfits=args.outfits, near=args.near, overwrite=args.overwrite,
                             lighting="mixed" if args.style == "mixed" else "source",
                             progress=not args.quiet)  # fmt: skip
            print(f"wrote {args.images} images ({args.size[0]}x{args.size[1]}) to {out}")
    except SynthArgumentError as err:
        print(f"uss-synth: error: {err}", file=sys.stderr)
        return 2
    except FileExistsError as err:
        print(f"uss-synth: error: {err}", file=sys.stderr)
        return 2
    except UssSlamError as err:
        print(f"uss-synth: error: {err}", file=sys.stderr)
        return err.exit_code  # 1; 2 for an --out another process is rendering
    except KeyboardInterrupt as interrupt:  # Ctrl-C or SIGTERM
        return report_interrupt("uss-synth", interrupt, "nothing was written")
    print(f"done in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

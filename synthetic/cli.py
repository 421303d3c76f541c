"""``uss-synth``: render synthetic TUM RGB-D sequences, VOC-layout sets and the demo data set."""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import cv2
import numpy as np
import yaml
from PIL import Image
from tqdm import tqdm

from uss_slam.core.classes import CLASS_NAMES, voc_lut
from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import read_file_list

from .motion import PRESETS
from .output import SynthArgumentError, check_output, parse_size, staged_output
from .sequence import render_sequence
from .styles import STYLES
from .voc import render_voc

DEMO_TRAIN_PRESETS = ("walking_xyz", "walking_rpy", "walking_halfsphere", "sitting_static")
DEMO_SLAM_PRESETS = ("walking_xyz", "static_xyz")


class _Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments on one line with exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _size(text: str) -> tuple[int, int]:
    try:
        return parse_size(text)
    except SynthArgumentError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _positive(minimum: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return parse


def _frames_or_skip(text: str) -> int:
    value = _positive(0)(text)
    if value == 1:
        raise argparse.ArgumentTypeError("must be 0 (skip) or >= 2, got 1")
    return value


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
            "arguments => byte-identical files. Output folders appear only when complete."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"sequence presets:\n{presets}",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="{sequence,voc,demo}")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
        p.add_argument(
            "--out", type=Path, required=True, help="output folder (must be new or empty)"
        )
        p.add_argument(
            "--overwrite",
            action="store_true",
            help="replace a non-empty output folder (only after rendering succeeded)",
        )
        p.add_argument("--quiet", action="store_true", help="no progress bar")  # fmt: skip

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
        type=_positive(2),
        default=120,
        help="number of frames at 30 Hz (>= 2, default: 120)",
    )
    seq.add_argument(
        "--size",
        type=_size,
        default=(640, 480),
        metavar="WxH",
        help="image size (default: 640x480)",
    )
    seq.add_argument("--style", choices=STYLES, default="target",
                     help="source: clean and evenly lit; target: Kinect-like blur, noise, colour "
                          "cast, depth noise and holes (default: target)")  # fmt: skip
    common(seq)

    voc = sub.add_parser(
        "voc",
        help="a PASCAL VOC 2012-layout segmentation set (source style)",
        description=_wrap(
            "Render OUT/VOCdevkit/VOC2012 with JPEGImages/ (JPEG quality 90), SegmentationClass/ "
            "(palette PNGs: person 15, chair 9, tvmonitor 20, 255 void band along outlines) and "
            "ImageSets/Segmentation/{train,val,trainval}.txt (every fifth image is val). Every "
            "image is a new random layout and viewpoint showing a person, chair or monitor."
        ),
    )
    voc.add_argument(
        "--images", type=_positive(1), default=200, help="number of images (default: 200)"
    )
    voc.add_argument(
        "--size",
        type=_size,
        default=(320, 240),
        metavar="WxH",
        help="image size (default: 320x240)",
    )
    common(voc)

    demo = sub.add_parser(
        "demo",
        help="the demo data set (VOC source set, target training / validation / SLAM sequences)",
        description=_wrap(
            "Render the demo data set used by `make demo`: OUT/voc (source VOC set), "
            "OUT/target_train/<preset> (target style, unlabelled use), OUT/target_val/walking_xyz "
            "(target style, another seed, labels for validation), OUT/slam/<preset> (target "
            "style, 640x480, for the SLAM evaluation). Prints a summary at the end."
        ),
    )
    demo.add_argument(
        "--out", type=Path, required=True, help="output folder (must be new or empty)"
    )
    demo.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    demo.add_argument("--seed", type=int, default=0, help="base seed (default: 0)")
    demo.add_argument(
        "--voc-images", type=_positive(0), default=400, help="VOC images, 0 to skip (default: 400)"
    )
    demo.add_argument(
        "--voc-size",
        type=_size,
        default=(320, 240),
        metavar="WxH",
        help="size of the VOC images (default: 320x240)",
    )
    demo.add_argument(
        "--train-frames",
        type=_frames_or_skip,
        default=100,
        help="frames per target training sequence, 0 to skip (default: 100)",
    )
    demo.add_argument(
        "--val-frames",
        type=_frames_or_skip,
        default=100,
        help="frames of the labelled target validation sequence, 0 to skip (default: 100)",
    )
    demo.add_argument(
        "--train-size",
        type=_size,
        default=(320, 240),
        metavar="WxH",
        help="size of training and validation sequences (default: 320x240)",
    )
    demo.add_argument(
        "--slam-frames",
        type=_frames_or_skip,
        default=300,
        help="frames per SLAM evaluation sequence, 0 to skip (default: 300)",
    )
    demo.add_argument("--slam-size", type=_size, default=(640, 480), metavar="WxH", help="size of the SLAM sequences (default: 640x480)")  # fmt: skip
    demo.add_argument(
        "--workers",
        type=_positive(1),
        default=min(2, os.cpu_count() or 1),
        help="processes rendering the parts in parallel (default: min(2, CPUs))",
    )
    demo.add_argument("--reuse", action="store_true",
                      help="if OUT already holds a complete demo made with the same arguments "
                           "(its demo.yaml), keep it and only print the summary")  # fmt: skip
    return parser


def _demo_record(args: argparse.Namespace) -> dict:
    """The arguments that determine the demo's content (not --workers, --quiet, ...)."""
    keys = ("seed", "voc_images", "voc_size", "train_frames", "val_frames", "train_size",
            "slam_frames", "slam_size")  # fmt: skip
    record = {k: list(v) if isinstance(v, tuple) else v for k, v in vars(args).items() if k in keys}
    return {"generator": "uss-synth demo", **record}


def _reusable(args: argparse.Namespace) -> bool:
    record = Path(args.out) / "demo.yaml"
    try:
        return yaml.safe_load(record.read_text()) == _demo_record(args)
    except (OSError, yaml.YAMLError):
        return False


def run_demo(args: argparse.Namespace) -> Path:
    """Render the demo data set into ``args.out`` (all-or-nothing) and return its path.

    The parts (the VOC set and each sequence) are independent tasks, run on ``args.workers``
    processes; the result does not depend on the number of workers.
    """
    progress = not args.quiet
    with staged_output(args.out, args.overwrite) as tmp:
        (tmp / "demo.yaml").write_text(yaml.safe_dump(_demo_record(args), sort_keys=False))
        tasks: list[tuple[str, Callable[..., Path], dict]] = []
        if args.voc_images:
            tasks.append(("voc", render_voc, dict(out_dir=tmp / "voc", images=args.voc_images,
                                                  size=args.voc_size, seed=args.seed)))  # fmt: skip
        if args.train_frames:
            for k, preset in enumerate(DEMO_TRAIN_PRESETS):
                tasks.append((f"target_train/{preset}", render_sequence, dict(
                    out_dir=tmp / "target_train" / preset, preset=preset, frames=args.train_frames,
                    size=args.train_size, seed=args.seed + 1 + k, style="target")))  # fmt: skip
        if args.val_frames:
            tasks.append(("target_val/walking_xyz", render_sequence, dict(
                out_dir=tmp / "target_val" / "walking_xyz", preset="walking_xyz",
                frames=args.val_frames, size=args.train_size, seed=args.seed + 100,
                style="target")))  # fmt: skip
        if args.slam_frames:
            for preset in DEMO_SLAM_PRESETS:
                tasks.append((f"slam/{preset}", render_sequence, dict(
                    out_dir=tmp / "slam" / preset, preset=preset, frames=args.slam_frames,
                    size=args.slam_size, seed=args.seed, style="target")))  # fmt: skip
        if args.workers <= 1 or len(tasks) <= 1:
            for _, fn, kwargs in tasks:
                fn(**kwargs, progress=progress)
        else:
            # biggest first, so that the long SLAM sequences do not start last
            tasks.sort(key=lambda task: -_cost(task[2]))
            with ProcessPoolExecutor(max_workers=args.workers) as pool:
                futures = [pool.submit(fn, **kwargs) for _, fn, kwargs in tasks]
                names = {f: name for f, (name, _, _) in zip(futures, tasks, strict=True)}
                bar = tqdm(total=len(futures), desc="demo parts", unit="part", disable=not progress)
                for future in as_completed(futures):
                    future.result()
                    bar.set_postfix_str(names[future])
                    bar.update()
                bar.close()
    return args.out


def _cost(kwargs: dict) -> float:
    """Rough rendering cost of a demo task (pixels times frames or images)."""
    w, h = kwargs["size"]
    return w * h * kwargs.get("frames", kwargs.get("images", 1)) * (2 if "frames" in kwargs else 1)


def _share(labels: list[Path]) -> np.ndarray:
    counts = np.zeros(256, np.int64)
    for path in labels:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        counts += np.bincount(img.reshape(-1), minlength=256)
    return counts


def summarize(root: Path) -> str:
    """A human-readable summary of a demo folder: counts, sizes, class pixel shares."""
    lines = [f"demo data set in {root.resolve()}"]

    def shares(counts: np.ndarray) -> str:
        valid = counts[: len(CLASS_NAMES)].sum()
        parts = [f"{n} {100 * counts[i] / max(valid, 1):.1f}%" for i, n in enumerate(CLASS_NAMES)]
        return ", ".join(parts)

    voc = root / "voc" / "VOCdevkit" / "VOC2012"
    if voc.is_dir():
        train = (voc / "ImageSets" / "Segmentation" / "train.txt").read_text().split()
        val = (voc / "ImageSets" / "Segmentation" / "val.txt").read_text().split()
        pngs = sorted((voc / "SegmentationClass").glob("*.png"))
        counts = np.zeros(256, np.int64)
        for p in pngs:
            counts += np.bincount(np.asarray(Image.open(p)).reshape(-1), minlength=256)
        lut = voc_lut()
        ours = np.zeros(256, np.int64)
        np.add.at(ours, lut, counts)
        w, h = Image.open(pngs[0]).size
        void = 100 * counts[255] / counts.sum()
        lines.append(f"  voc/VOCdevkit/VOC2012: {len(train)} train + {len(val)} val images, {w}x{h}, "
                     f"source style; pixels: {shares(ours)} (void {void:.1f}%)")  # fmt: skip
    for group in ("target_train", "target_val", "slam"):
        folder = root / group
        if not folder.is_dir():
            continue
        for seq in sorted(p for p in folder.iterdir() if p.is_dir()):
            rgb = read_file_list(seq / "rgb.txt")
            labels = sorted((seq / "labels").glob("*.png"))
            counts = _share(labels[:: max(1, len(labels) // 20)])
            first = cv2.imread(str(rgb.resolve(0)), cv2.IMREAD_UNCHANGED)
            meta = (seq / "synthetic.yaml").read_text() if (seq / "synthetic.yaml").exists() else ""
            style = "target" if "style: target" in meta else "source"
            lines.append(f"  {group}/{seq.name}: {len(rgb)} frames, {first.shape[1]}x{first.shape[0]}, "
                         f"{style} style; pixels: {shares(counts)}")  # fmt: skip
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    start = time.perf_counter()
    try:
        if args.command == "demo" and args.reuse and _reusable(args):
            print(f"reusing the complete demo data set in {args.out} (same arguments)")
            print(summarize(args.out))
            return 0
        check_output(args.out, args.overwrite)
        if args.command == "sequence":
            out = render_sequence(args.out, preset=args.preset, frames=args.frames, size=args.size,
                                  seed=args.seed, style=args.style, overwrite=args.overwrite,
                                  progress=not args.quiet)  # fmt: skip
            print(f"wrote {args.frames} frames ({args.preset}, {args.style}, "
                  f"{args.size[0]}x{args.size[1]}) to {out}")  # fmt: skip
        elif args.command == "voc":
            out = render_voc(args.out, images=args.images, size=args.size, seed=args.seed,
                             overwrite=args.overwrite, progress=not args.quiet)  # fmt: skip
            print(f"wrote {args.images} images ({args.size[0]}x{args.size[1]}) to {out}")
        else:
            out = run_demo(args)
            print(summarize(out))
    except SynthArgumentError as err:
        print(f"uss-synth: error: {err}", file=sys.stderr)
        return 2
    except FileExistsError as err:
        print(f"uss-synth: error: {err}", file=sys.stderr)
        return 2
    except UssSlamError as err:
        print(f"uss-synth: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("uss-synth: interrupted; nothing was written", file=sys.stderr)
        return 130
    print(f"done in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

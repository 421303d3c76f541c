"""Are the walkers missed because of what they wear? Swap their clothes and segment again. Reported
in docs/results/adaptation.md, "7. The source wardrobe: evidence, and a varied one at the standard
scale (2026-12-02)".

Renders one target-style sequence twice, frame for frame identical except for the people's
materials: once as ``uss-synth`` renders it (the target texture family's clothes, skin and hair)
and once with the people wearing the *source* family's outfits (the clothes the VOC-style
training images show), everything else (room, motion, lighting, Kinect-like noise and blur) the
target's. Each ONNX segmenter given then segments both, and the table reports its person IoU and
walker-pixel recall on each. A large rise with source outfits says the segmenter fails on the
target clothing rather than on the target image style.

Use the validation preset and seed (``walking_xyz``, seed 100 for ``uss-demo`` seed 0), not an
evaluation sequence: this is a diagnosis of the training data, not a test.

    python studies/outfit_swap.py --models /path/exports/*/*.onnx --frames 40
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.progress import progress_bar
from uss_slam.core.seg_metrics import confusion_matrix, iou_per_class
from uss_slam.synthetic.sequence import SequenceRenderer
from uss_slam.synthetic.textures import TextureBank, texture_bank, with_people

PERSON = CLASS_NAMES.index("person")


def swapped_bank(target_variant: int, source_variant: int) -> TextureBank:
    """The target bank with the people's materials of source bank ``source_variant``."""
    source = texture_bank("source", source_variant)
    return with_people(texture_bank("target", target_variant), lambda i, _: source.images[i])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="+", type=Path, required=True, help="ONNX segmenters")
    ap.add_argument("--preset", default="walking_xyz")
    ap.add_argument("--seed", type=int, default=100, help="sequence seed (default: validation)")
    ap.add_argument("--frames", type=int, default=40, help="frames rendered (every 5th of 5x)")
    ap.add_argument("--size", default="320x240", help="WxH (default: the training size)")
    ap.add_argument("--source-variant", type=int, default=0, help="source bank of the swap")
    args = ap.parse_args(argv)
    for m in args.models:
        if not m.is_file():
            ap.error(f"{m}: no such ONNX model")
    w, h = (int(v) for v in args.size.lower().split("x"))
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    models = {m: OnnxSegmenter(m, threads=1) for m in args.models}
    seq = SequenceRenderer(args.preset, args.frames * 5, (w, h), args.seed, "target")
    banks = {"target outfits": seq.bank, "source outfits": swapped_bank(0, args.source_variant)}
    conf = {(m, k): np.zeros((len(CLASS_NAMES),) * 2, np.int64) for m in models for k in banks}
    for i in progress_bar(range(0, seq.frames, 5), desc="frames", unit="frame"):
        for kind, bank in banks.items():
            seq.bank = bank
            fr = seq.frame(i)
            for m, seg in models.items():
                conf[m, kind] += confusion_matrix(fr.labels, seg.infer(fr.rgb), len(CLASS_NAMES))
    print(f"\n{args.preset} seed {args.seed}, {len(range(0, seq.frames, 5))} frames, {w}x{h}\n")
    print("| model | person IoU, target outfits | person IoU, source outfits | "
          "person recall, target | person recall, source |")  # fmt: skip
    print("|---|---|---|---|---|")
    for m in models:
        cells = []
        for kind in banks:
            c = conf[m, kind]
            cells.append((iou_per_class(c)[PERSON], c[PERSON, PERSON] / max(c[PERSON].sum(), 1)))
        print(f"| {m.stem} | {cells[0][0]:.3f} | {cells[1][0]:.3f} | {cells[0][1]:.3f} | "
              f"{cells[1][1]:.3f} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

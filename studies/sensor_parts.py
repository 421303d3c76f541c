"""Which part of the Kinect-like target style carries a hand-held sequence's per-frame ATE (the
"fast part" a keyframe back end cannot remove)? The sequence is rendered with one part of the style
switched off at a time, then run with the tracker alone and with the default back end, medians of
repeats. Reported in docs/results/slam.md, "2026-12-04/05 — what a back end can remove on a
hand-held camera", and BENCHMARKS.md, "SLAM back end (local BA, loop closing, PROSAC)".

Command::

    python studies/sensor_parts.py --data DIR --preset handheld_rpy --seeds 0 1 2 \\
        --repeats 3 [--parts full no_blur no_image_noise exact_depth] [--json F]

Parts (every other part of the style and the preset's sensor timing, e.g. ``handheld_rpy``'s
rolling shutter, stay as they are):

- ``full``: the target style as ``uss-synth`` renders it;
- ``no_blur``: no motion blur during the exposure;
- ``no_image_noise``: no signal-dependent sensor noise on the colour image;
- ``exact_depth``: the rendered depth as is (no axial noise, no holes, no minimum range); the
  sequence still declares the style's depth noise, so the back end models it as in ``full``.

Per run: ATE RMSE and its slow / fast parts (``ate_bands`` over 0.5 s, as
``slam_backend.py``). Sequences are rendered into
``DIR/<preset>_<part>_<frames>_<W>x<H>_seed<S>`` and reused.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from unittest import mock

import numpy as np

from uss_slam.synthetic import sequence as sequence_module
from uss_slam.synthetic.sequence import render_sequence
from uss_slam.synthetic.styles import depth_to_png, target_rgb
from uss_slam.testing.harness_runs import run_cell

PARTS = ("full", "no_blur", "no_image_noise", "exact_depth")
VARIANTS = ("tracker", "loop")  # the tracker alone; the default back end (local BA + loop)


class _Silent:
    """A noise pool whose colour-image noise is zero; the depth's noise stays as it was."""

    def __init__(self, pool) -> None:
        self.pool = pool

    def normal16(self, rng, shape):
        self.pool.normal16(rng, shape)  # the same draws, so the depth gets the same noise
        return np.zeros(shape, np.int8)

    def uniform8(self, rng, shape):
        return self.pool.uniform8(rng, shape)


@contextmanager
def style_without(part: str) -> Iterator[None]:
    """The target style with ``part`` switched off while rendering (``full``: unchanged)."""
    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; choose from {', '.join(PARTS)}")
    if part == "no_blur":
        patch = mock.patch.object(
            sequence_module, "target_rgb", lambda rgb, flow, *a: target_rgb(rgb, None, *a)
        )
    elif part == "no_image_noise":
        patch = mock.patch.object(
            sequence_module,
            "target_rgb",
            lambda rgb, flow, gain, rng, pool: target_rgb(rgb, flow, gain, rng, _Silent(pool)),
        )
    elif part == "exact_depth":
        patch = mock.patch.object(
            sequence_module, "target_depth", lambda depth, rng, pool: depth_to_png(depth)
        )
    else:
        yield
        return
    with patch:
        yield


def render(data: Path, preset: str, part: str, frames: int, size: tuple[int, int], seed: int
           ) -> Path:  # fmt: skip
    path = data / f"{preset}_{part}_{frames}_{size[0]}x{size[1]}_seed{seed}"
    if not (path / "rgb.txt").is_file():
        print(f"rendering {path} ...", file=sys.stderr, flush=True)
        with style_without(part):
            render_sequence(path, preset=preset, frames=frames, size=size, seed=seed)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("outputs/bench/sensor_parts"))
    parser.add_argument("--preset", default="handheld_rpy")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--size", default="640x480", help="WxH (default 640x480)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS)
    parser.add_argument("--repeats", type=int, default=3,
                        help="runs per cell, perturbed as slam.repeats (the median run is kept)")  # fmt: skip
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats: must be >= 1, got {args.repeats}")
    size = tuple(int(v) for v in args.size.lower().split("x"))
    results: dict[str, dict[str, list[dict]]] = {}
    for seed in args.seeds:
        for part in args.parts:
            path = render(args.data, args.preset, part, args.frames, size, seed)
            for variant in VARIANTS:
                r = run_cell(path, variant, [], args.repeats)
                r["seed"] = seed
                results.setdefault(part, {}).setdefault(variant, []).append(r)
                print(f"{args.preset} seed {seed} {part:15s} {variant:8s} ATE "
                      f"{1000 * r['ate_rmse']:.1f} mm (slow {1000 * r['ate_slow']:.1f}, fast "
                      f"{1000 * r['ate_fast']:.1f})", flush=True)  # fmt: skip
    print(f"\nmedians over seeds {args.seeds}, ATE [mm] (slow, fast):")
    print("| part | " + " | ".join(VARIANTS) + " |\n" + "|---" * (len(VARIANTS) + 1) + "|")
    for part, variants in results.items():
        cells = []
        for variant in VARIANTS:
            rows = variants[variant]
            m = {k: 1000 * statistics.median(r[k] for r in rows)
                 for k in ("ate_rmse", "ate_slow", "ate_fast")}  # fmt: skip
            cells.append(f"{m['ate_rmse']:.1f} ({m['ate_slow']:.1f}, {m['ate_fast']:.1f})")
        print(f"| {part} | " + " | ".join(cells) + " |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

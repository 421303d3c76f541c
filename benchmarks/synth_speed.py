"""How fast does the synthetic world render on a single core, against the naive ray caster in the
same run (``python benchmarks/synth_speed.py``)? Reported in BENCHMARKS.md, "Synthetic world
rendering".

For each size (320x240, 640x480) and style (source, target) renders frames of ``walking_xyz``
with depth and labels (``SequenceRenderer.frame``: colour, depth PNG array, labels, style
effects), and in the same run two references:

- ``naive``: the same frames with screen-space culling off (every primitive tested against every
  pixel), i.e. the straightforward ray caster (clean render only, like the ``source`` style);
- ``png``: writing the frame's three PNGs (rgb, depth, labels) with the writer's settings,
  reported separately (not included in the rendering rate).

Prints the median of ``--repeats`` runs of ``--frames`` frames (frames/s) and the ratios.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"  # one core: set before numpy is imported

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402

from uss_slam.synthetic.output import write_png  # noqa: E402
from uss_slam.synthetic.renderer import Renderer  # noqa: E402
from uss_slam.synthetic.sequence import SequenceRenderer  # noqa: E402


def _rate(fn, frames: list[int], repeats: int) -> tuple[float, float]:
    """Median frames per second of ``fn(index)`` over ``repeats`` passes of ``frames``: by the
    wall clock and by this process's CPU time (the per-core rate on a busy machine)."""
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        for i in frames:
            fn(i)
        wall.append(len(frames) / (time.perf_counter() - start))
        cpu.append(len(frames) / (time.process_time() - start_cpu))
    return statistics.median(wall), statistics.median(cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=30, help="frames per repeat (default 30)")
    parser.add_argument("--repeats", type=int, default=5, help="repeats (default 5)")
    parser.add_argument("--naive-frames", type=int, default=6, help="frames per naive repeat")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores visible, "
          f"single-threaded; walking_xyz; median of {args.repeats} repeats")  # fmt: skip
    print("rates in frames/s, wall clock / CPU time")
    print("size     style   render (wall/cpu)  naive (wall/cpu)  speed-up (cpu)  png write (cpu)")
    frames = list(range(0, 10 * args.frames, 10))  # spread over the sequence: people come and go
    for size in ((320, 240), (640, 480)):
        for style in ("source", "target"):
            seq = SequenceRenderer("walking_xyz", 10 * args.frames, size, 0, style)
            seq.frame(0)  # warm-up: textures, caches
            fps = _rate(seq.frame, frames, args.repeats)
            naive = Renderer(seq.camera, cull=False)

            def naive_frame(i: int, seq=seq, naive=naive) -> None:
                t = seq.time(seq.stamps[i])
                naive.render(seq.motion.pose(t), seq.scene.room, seq.scene.prims_at(t),
                             seq.bank, seq.lighting)  # fmt: skip

            naive_fps = _rate(naive_frame, frames[: args.naive_frames], args.repeats)
            sample = seq.frame(frames[len(frames) // 2])
            with tempfile.TemporaryDirectory() as tmp:

                def write(i: int, tmp=Path(tmp), fr=sample) -> None:
                    write_png(tmp / f"{i}.png", fr.rgb)
                    write_png(tmp / f"{i}d.png", fr.depth)
                    write_png(tmp / f"{i}l.png", fr.labels)

                png_fps = _rate(write, frames, args.repeats)
            # the naive caster does no style work, so its speed-up is against a clean render
            ratio = f"{fps[1] / naive_fps[1]:.1f}x" if style == "source" else "-"
            print(f"{size[0]}x{size[1]:<4} {style:7} {fps[0]:8.1f} / {fps[1]:<6.1f}  "
                  f"{naive_fps[0]:7.1f} / {naive_fps[1]:<6.1f}  {ratio:>14}  {png_fps[1]:15.1f}")  # fmt: skip


if __name__ == "__main__":
    main()

"""How much CPU time does decoding a frame's PNGs take, with OpenCV's libpng alone (the system
zlib inflates) and with the image data inflated by ISA-L first (``core/png_inflate.py``)? And do
both give the same pixels? Reported in BENCHMARKS.md, "SLAM harness speed".

For each folder (``rgb``, ``depth``, ``labels`` of a TUM-layout sequence) the first ``--frames``
PNGs are read into memory, then decoded by both ways in turns, image by image, ``--rounds``
times; printed: the median thread CPU ms per image of each way and their ratio. Every image is
compared pixel for pixel first (an exit code of 1 where one differs).

    python benchmarks/png_decode.py --data outputs/bench/slam/walking_xyz_300_640x480_seed0
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.png_inflate import stored
from uss_slam.slam_eval.frontend.pools import one_thread_pools
from uss_slam.testing.machine import cpu_model

FLAGS = {"rgb": cv2.IMREAD_COLOR, "depth": cv2.IMREAD_UNCHANGED, "labels": cv2.IMREAD_UNCHANGED}
"""How the SLAM harness decodes each folder's images (core/images.py)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--data", type=Path, required=True, help="a TUM-layout sequence folder")
    parser.add_argument("--frames", type=int, default=100, help="PNGs per folder")
    parser.add_argument("--rounds", type=int, default=5, help="turns of the two ways")
    args = parser.parse_args()
    print(f"{args.data}: {args.frames} PNGs per folder, {args.rounds} rounds, {cpu_model()}, "
          f"load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    differ = False
    with one_thread_pools():
        for folder, flags in FLAGS.items():
            files = sorted((args.data / folder).glob("*.png"))[: args.frames]
            if files:
                differ |= not compare(folder, [f.read_bytes() for f in files], flags, args.rounds)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    sys.exit(1 if differ else 0)


def compare(folder: str, data: list[bytes], flags: int, rounds: int) -> bool:
    """Print the two ways' CPU ms per image of one folder; False where any pixel differs."""

    def libpng(d: bytes) -> np.ndarray:
        return cv2.imdecode(np.frombuffer(d, np.uint8), flags)

    def isal(d: bytes) -> np.ndarray:
        return cv2.imdecode(np.frombuffer(stored(d), np.uint8), flags)

    same = all(np.array_equal(libpng(d), isal(d)) for d in data)
    times: dict[str, list[float]] = {"libpng": [], "isal": []}
    for k in range(rounds):  # image by image in turns: a busy machine's drift hits both ways
        spent = {"libpng": 0.0, "isal": 0.0}
        for j, d in enumerate(data):
            for name in ("libpng", "isal") if (j + k) % 2 == 0 else ("isal", "libpng"):
                start = time.thread_time()
                (libpng if name == "libpng" else isal)(d)
                spent[name] += time.thread_time() - start
        for name, total in spent.items():
            times[name].append(1000.0 * total / len(data))
    a, b = (statistics.median(times[n]) for n in ("libpng", "isal"))
    size = sum(len(d) for d in data) / len(data) / 1024
    print(f"{folder:7s} ({size:.0f} kB a file): libpng alone {a:.2f} CPU ms, ISA-L inflate + libpng "
          f"{b:.2f} ({b / a:.2f}x); same pixels: {same}")  # fmt: skip
    return same


if __name__ == "__main__":
    main()

"""How fast is segmenter inference per frame with onnxruntime (FP32, INT8) against PyTorch eager, in
the same process (``python benchmarks/segmenter_speed.py``)? Reported in BENCHMARKS.md, "Segmenter
inference (PyTorch eager vs onnxruntime)".

For the demo model (DeepLab-v2 on the small backbone, ``configs/model/net/deeplab_small.yaml``)
and the paper's ResNet-101 DeepLab-v2, random weights (nothing is downloaded; timings do not
depend on the weight values), exported with ``uss-export``'s :func:`export_segmenter` (so the
model is verified first). The BatchNorm statistics of the random nets are set from a few random
images, so activations and logits have trained-model magnitudes and verification is meaningful.

Per-frame latency of the whole contract, one uint8 RGB frame in, logits + labels out at the
frame's size (normalisation, both layout changes, upsampling and argmax included on both sides):

- ``eager``: :class:`SegmenterExport` under ``torch.inference_mode`` (``torch.set_num_threads``);
- ``ort``: onnxruntime FP32 on the exported model (``intra_op_num_threads``, CPU provider);
- ``int8``: onnxruntime on the static INT8 model (with ``--calibration DIR``, a TUM folder).

Same process, same thread count, the variants interleaved within each repeat; median of
``--repeats`` after one warm-up; the ratios eager/ort and ort/int8 are the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import onnxruntime as ort
import torch

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.onnx_contract import INPUT_NAME
from uss_slam.export import (
    SegmenterExport,
    export_segmenter,
    make_session,
    quantize_int8,
    read_calibration_frames,
    verification_images,
)
from uss_slam.models import DeepLabV2
from uss_slam.testing.machine import benchmark_metadata

BACKBONES = {"demo": "resnet_small", "resnet101": "resnet101"}


def random_net(backbone: str, seed: int = 0) -> DeepLabV2:
    """A random DeepLabV2 whose BatchNorm running statistics come from random images."""
    torch.manual_seed(seed)
    net = DeepLabV2(len(CLASS_NAMES), backbone, freeze_bn=False)
    for module in net.modules():
        if isinstance(module, torch.nn.BatchNorm2d):
            module.momentum = None  # cumulative average over the passes below
    net.train()
    with torch.no_grad():
        for _ in range(3):
            net(torch.randn(2, 3, 97, 97))
    return net.eval()


def bench(
    name: str,
    net: DeepLabV2,
    sizes: list[tuple[int, int]],
    threads: list[int],
    repeats: int,
    workdir: Path,
    calibration: Path | None,
) -> list[dict]:
    metadata = benchmark_metadata(name)
    # Random ResNet-101 logits reach the hundreds: float32 reordering (BN folded into the
    # convolutions) then exceeds the absolute 1e-4 meant for trained models; printed below.
    result = export_segmenter(net, workdir / f"{name}.onnx", metadata, max_logit_diff=1e-2)
    print(
        f"{name}: exported and verified (max |logit diff| {result.verify['max_abs_logit_diff']:.1e},"
        f" largest |logit| {result.verify['max_abs_logit']:.1f})",
        flush=True,
    )
    int8_path = None
    if calibration is not None:
        calib, evaluation = read_calibration_frames(calibration, frames=8)
        int8_path = workdir / f"{name}.int8.onnx"
        q = quantize_int8(result.path, int8_path, calib, evaluation, threads=2, repeats=1)
        print(f"{name}: INT8 label agreement with FP32 {q['label_agreement_vs_fp32']:.4f}")
    wrapper = SegmenterExport(net).eval()
    rows = []
    for n_threads in threads:
        torch.set_num_threads(n_threads)
        sessions = {"ort": make_session(result.path, n_threads)}
        if int8_path is not None:
            sessions["int8"] = make_session(int8_path, n_threads)
        for height, width in sizes:
            image = verification_images((height, width), batch=1, seed=11)
            tensor = torch.from_numpy(image)

            def eager(tensor: torch.Tensor = tensor) -> None:
                with torch.inference_mode():
                    wrapper(tensor)

            runs = {"eager": eager}
            for key, session in sessions.items():
                runs[key] = lambda s=session, x=image: s.run(None, {INPUT_NAME: x})
            times: dict[str, list[float]] = {key: [] for key in runs}
            for fn in runs.values():
                fn()  # warm-up
            for _ in range(repeats):
                for key, fn in runs.items():
                    start = time.perf_counter()
                    fn()
                    times[key].append((time.perf_counter() - start) * 1000)
            row = {
                "model": name,
                "size": f"{width}x{height}",
                "threads": n_threads,
                **{f"{key}_ms": statistics.median(v) for key, v in times.items()},
            }
            row["eager_over_ort"] = row["eager_ms"] / row["ort_ms"]
            if "int8_ms" in row:
                row["ort_over_int8"] = row["ort_ms"] / row["int8_ms"]
                ref = sessions["ort"].run(None, {INPUT_NAME: image})[1]
                got = sessions["int8"].run(None, {INPUT_NAME: image})[1]
                row["int8_label_agreement"] = float((ref == got).mean())
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", default="demo,resnet101", help="demo,resnet101")
    parser.add_argument("--sizes", default="640x480,320x240", help="WxH list")
    parser.add_argument("--threads", default="2,1", help="thread counts")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--calibration", type=Path, help="TUM folder: also time an INT8 model")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args()
    sizes = []
    for text in args.sizes.split(","):
        width, height = (int(v) for v in text.lower().split("x"))
        sizes.append((height, width))
    threads = [int(v) for v in args.threads.split(",")]
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch "
        f"{torch.__version__}, onnxruntime {ort.__version__}; load {os.getloadavg()}",
        flush=True,
    )
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.models.split(","):
            net = random_net(BACKBONES[name])
            rows += bench(name, net, sizes, threads, args.repeats, Path(tmp), args.calibration)
    print(f"load at the end {os.getloadavg()}")
    header = "| model | size | threads | eager ms | onnxruntime ms | eager / ort |"
    int8 = any("int8_ms" in r for r in rows)
    if int8:
        header += " INT8 ms | ort / INT8 | INT8 label agreement |"
    print("\n" + header)
    print("|" + "---|" * (header.count("|") - 1))
    for r in rows:
        line = (
            f"| {r['model']} | {r['size']} | {r['threads']} | {r['eager_ms']:.1f} | "
            f"{r['ort_ms']:.1f} | {r['eager_over_ort']:.2f}× |"
        )
        if int8:
            line += (
                f" {r['int8_ms']:.1f} | {r['ort_over_int8']:.2f}× | "
                f"{r['int8_label_agreement']:.4f} |"
            )
        print(line)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()

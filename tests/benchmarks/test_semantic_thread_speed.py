"""``benchmarks/semantic_thread_speed.py``: a network in the semantic thread and the oracle at its
measured latency, both timed in one command; a clear error for a missing input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from shared_helpers import colour_model, segmenter_props

from uss_slam.core.classes import CLASS_NAMES

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "semantic_thread_speed.py"


def test_times_the_network_and_the_oracle_at_its_latency(synthetic_sequence, tmp_path) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=12, size=(160, 120))
    # labels every pixel background: its own masks flag nothing
    model = colour_model(tmp_path / "m.onnx", segmenter_props(CLASS_NAMES), label_map=(0, 0, 0, 0))
    work = tmp_path / "work"
    args = [sys.executable, str(SCRIPT), "--sequence", str(seq), "--model", str(model)]
    options = ["--repeats", "2", "--nice", "5", "--work", str(work)]
    options += ["--set", "slam.local_ba_params.min_interval_s=0.25"]
    done = subprocess.run([*args, *options], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    runs = json.loads((work / "runs.json").read_text())[seq.name]
    assert [len(v) for v in runs.values()] == [2, 2, 2, 2]
    for net, oracle in zip(runs["network"], runs["oracle"], strict=True):
        assert net["first_s"] > 0 and net["masks"] >= 1 and net["network_cpu_s"] > 0
        assert net["tracking_fps"] > 0 and net["tracking_cpu_ms"] > net["main_cpu_ms"] > 0
        assert oracle["network_cpu_s"] is None
        # the oracle waited the network's measured latency, on the wall clock
        assert oracle["first_s"] >= min(net["latency_s"], net["first_s"]) * 0.9
    metrics = json.loads((work / "runs" / seq.name / "0" / "oracle" / "metrics.json").read_text())
    assert metrics["segmenter"] == "labels"
    assert metrics["segmentation"]["semantic_thread"]["clock"] == "wall"
    nice = json.loads(
        (work / "runs" / seq.name / "1" / "network_nice" / "metrics.json").read_text()
    )
    assert nice["settings"]["slam"]["semantic_nice"] == 5
    assert metrics["settings"]["slam"]["local_ba_params"]["min_interval_s"] == 0.25  # --set
    for name in ("network", "network_labels"):
        net = json.loads((work / "runs" / seq.name / "0" / name / "metrics.json").read_text())
        assert net["segmenter"] == "onnx:m.onnx"
        assert net["segmentation"]["semantic_thread"]["clock"] == "wall"
    # the network's cost with the ground truth's masks (people), or with its own (none)
    truth, own = runs["network"][0]["flagged"], runs["network labels"][0]["flagged"]
    assert truth["semantic"] > own["semantic"] == 0
    assert f"| {seq.name} | network |" in done.stdout and f"| {seq.name} | oracle |" in done.stdout
    missing = subprocess.run(
        [*args[:3], str(tmp_path / "nope"), "--model", str(model)], capture_output=True, text=True
    )
    assert missing.returncode == 2 and f"{tmp_path / 'nope'}: not found" in missing.stderr
    bad = subprocess.run([*args, "--set", "slam.local_ba"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--set: expected KEY=VALUE, got 'slam.local_ba'" in bad.stderr


def test_builds_an_int8_deeplab_once(synthetic_sequence, tmp_path) -> None:
    """Without ``--model`` the benchmark builds the INT8 DeepLab-v2 (here the demo's small
    backbone) into ``--work`` and reuses it."""
    seq = synthetic_sequence(preset="walking_xyz", frames=12, size=(160, 120))
    work = tmp_path / "work"
    args = [sys.executable, str(SCRIPT), "--sequence", str(seq), "--work", str(work)]
    args += ["--backbone", "resnet_small", "--build-only"]
    first = subprocess.run(args, capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    assert "built " in first.stdout and (work / "resnet_small.int8.onnx").is_file()
    again = subprocess.run(args, capture_output=True, text=True)
    assert again.returncode == 0 and "built " not in again.stdout

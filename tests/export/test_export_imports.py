"""The exporter needs only the shared core and the models (plus torch, onnx, onnxruntime, Hydra):
neither the trainer nor the dataset code; reading a checkpoint needs torch and the core only."""

from __future__ import annotations

import json
import subprocess
import sys

CODE = """
import importlib, json, pkgutil, sys

def ours(prefixes):
    return sorted(m for m in sys.modules if any(m == p or m.startswith(p + ".") for p in prefixes))

import uss_slam.models.checkpoint
checkpoint = ours(["uss_slam", "hydra", "omegaconf", "onnx", "onnxruntime", "lightning"])
import uss_slam.export as pkg
walked = [info.name for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")]
for name in walked:
    importlib.import_module(name)
export = ours(["uss_slam", "lightning"])
print(json.dumps({"checkpoint": checkpoint, "walked": walked, "export": export}))
"""


def test_imports_stay_on_lower_floors() -> None:
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, check=True)
    loaded = json.loads(out.stdout)
    floor0 = {"uss_slam", "uss_slam.core", "uss_slam.models"}
    assert {m.rsplit(".", 1)[0] for m in loaded["checkpoint"]} <= floor0
    assert "uss_slam.models.checkpoint" in loaded["checkpoint"]
    assert set(loaded["walked"]) >= {
        "uss_slam.export.checkpoint",
        "uss_slam.export.cli",
        "uss_slam.export.onnx",
        "uss_slam.export.outputs",
        "uss_slam.export.quantize",
        "uss_slam.export.verify",
        "uss_slam.export.wrapper",
    }
    packages = {".".join(m.split(".")[:2]) for m in loaded["export"]}
    assert packages <= {"uss_slam", "uss_slam.core", "uss_slam.models", "uss_slam.export"}

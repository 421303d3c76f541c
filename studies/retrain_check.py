"""Is a training reproducible bit for bit? Compare a retrained model with the study's: every
tensor of the two ``last.ckpt`` state dicts, and every initializer of the two exported ONNX
graphs (the ONNX files themselves differ in their ``uss_slam.checkpoint_sha256`` metadata,
because a checkpoint file records its own folder). Reported in docs/results/README.md, "the real
regime downstream".

A retrain is ``uss-train`` with the study training's own ``.hydra/overrides.yaml`` (keys of an
earlier version renamed as ``uss-train``'s ``MOVED_KEYS`` says; ``paths.output_dir`` and
``paths.log_dir`` pointed at ``RETRAIN/<model>``), then ``uss-export`` of its ``last.ckpt`` to
``RETRAIN/<model>/retrain.onnx``::

    python studies/retrain_check.py STUDY RETRAIN MODEL [MODEL ...]

Discriminator keys of checkpoints written before the methods owned their discriminators
(``d_aux.*``, ``d_main.*``) are read as ``method.d_aux.*`` / ``method.d_main.*``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def compare(study: Path, retrain: Path, model: str) -> dict[str, object]:
    import onnx
    import torch
    from onnx import numpy_helper

    def state(path: Path) -> dict:
        if not path.is_file():
            raise SystemExit(f"retrain_check: error: {path}: no such checkpoint")
        blob = torch.load(path, map_location="cpu", weights_only=False)["state_dict"]
        old = ("d_aux.", "d_main.")
        return {("method." + k if k.startswith(old) else k): v for k, v in blob.items()}

    def initializers(path: Path) -> dict[str, np.ndarray]:
        if not path.is_file():
            raise SystemExit(f"retrain_check: error: {path}: no such export")
        graph = onnx.load(str(path)).graph
        return {t.name: numpy_helper.to_array(t) for t in graph.initializer}

    a = state(study / "train" / model / "checkpoints" / "last.ckpt")
    b = state(retrain / model / "checkpoints" / "last.ckpt")
    ia = initializers(study / "exports" / model / f"{model}.onnx")
    ib = initializers(retrain / model / "retrain.onnx")
    equal = sum(bool(k in b and torch.equal(v, b[k])) for k, v in a.items())
    return {
        "model": model,
        "tensors_equal": equal,
        "tensors": len(a),
        "keys_equal": a.keys() == b.keys(),
        "onnx_equal": ia.keys() == ib.keys() and all(np.array_equal(ia[k], ib[k]) for k in ia),
        "initializers": len(ia),
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("study", type=Path)
    p.add_argument("retrain", type=Path)
    p.add_argument("models", nargs="+")
    a = p.parse_args(argv)
    for model in a.models:
        r = compare(a.study, a.retrain, model)
        print(f"{model}: checkpoint tensors equal {r['tensors_equal']}/{r['tensors']} (same keys: "
              f"{r['keys_equal']}); ONNX initializers equal: {r['onnx_equal']} "
              f"({r['initializers']})")  # fmt: skip


if __name__ == "__main__":
    main()

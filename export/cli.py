"""``uss-export``: a ``uss-train`` checkpoint -> a self-describing, verified ONNX segmenter.

Examples::

    uss-export ckpt_path=outputs/train/runs/demo/<time>/checkpoints/last.ckpt
    uss-export ckpt_path=PATH name=demo_aux head=aux out=/tmp/demo_aux.onnx
    uss-export ckpt_path=PATH int8=true calibration.root=outputs/demo/data/slam/walking_xyz

Every option is checked first (types, opset, sizes), then the calibration frames are read (with
``int8=true``), then the checkpoint; only then is anything written. A bad input ends with one
line on stderr naming the key or file, and exit code 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hydra
import torch
from omegaconf import DictConfig, OmegaConf

from uss_slam.core.cli import hydra_task, run_hydra_app
from uss_slam.core.errors import UssSlamError
from uss_slam.core.onnx_contract import HEADS
from uss_slam.export.checkpoint import run_name
from uss_slam.export.onnx import check_options, export_checkpoint
from uss_slam.export.outputs import ExportResult
from uss_slam.export.quantize import CalibrationSet

PROG = "uss-export"


def _value(cfg: DictConfig, key: str) -> Any:
    value = OmegaConf.select(cfg, key, default=None)
    return OmegaConf.to_container(value) if OmegaConf.is_config(value) else value


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _int(cfg: DictConfig, key: str, *, optional: bool = False, minimum: int = 1) -> int | None:
    value = _value(cfg, key)
    if value is None and optional:
        return None
    if not _is_int(value) or value < minimum:
        raise UssSlamError(f"{key} must be an integer >= {minimum}, got {value!r}")
    return value


def _number(cfg: DictConfig, key: str, low: float, high: float = math.inf) -> float | None:
    """A number in ``(low, high]``, or null."""
    value = _value(cfg, key)
    if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
        raise UssSlamError(f"{key} must be a number or null, got {value!r}")
    if value is not None and not low < value <= high:
        within = f"> {low:g}" if math.isinf(high) else f"in ({low:g}, {high:g}]"
        raise UssSlamError(f"{key} must be {within} or null, got {value!r}")
    return None if value is None else float(value)


def _text(cfg: DictConfig, key: str, *, optional: bool = True) -> str | None:
    value = _value(cfg, key)
    if value is None and optional:
        return None
    if not isinstance(value, str) or not value:
        raise UssSlamError(f"{key} must be a non-empty string, got {value!r}")
    return value


@dataclass(frozen=True)
class ExportOptions:
    """``configs/export.yaml``, type-checked (see that file for each key)."""

    ckpt_path: Path
    out: Path
    head: str
    opset: int
    net_config: str | dict[str, Any] | None
    experiment: str | None
    dynamic_classes: tuple[str, ...]
    trace_size: Any
    verify_size: Any
    max_logit_diff: float | None
    min_label_agreement: float | None
    num_threads: int | None
    calibration_root: Path | None
    calibration_frames: int

    @classmethod
    def from_config(cls, cfg: DictConfig) -> ExportOptions:
        ckpt = _value(cfg, "ckpt_path")
        if ckpt is None:
            raise UssSlamError("ckpt_path=PATH is required (a uss-train .ckpt)")
        if not isinstance(ckpt, str) or not ckpt:
            raise UssSlamError(f"ckpt_path must be a file path, got {ckpt!r}")
        ckpt_path = Path(ckpt)
        head = _value(cfg, "head")
        if head not in HEADS:
            raise UssSlamError(f"head must be one of {HEADS}, got {head!r}")
        opset = _value(cfg, "opset")
        if not _is_int(opset):
            raise UssSlamError(f"opset must be an integer, got {opset!r}")
        dynamic = _value(cfg, "dynamic_classes")
        if not isinstance(dynamic, list) or not all(isinstance(c, str) for c in dynamic):
            raise UssSlamError(f"dynamic_classes must be a list of class names, got {dynamic!r}")
        net_config = _value(cfg, "net_config")
        if net_config is not None and not isinstance(net_config, (str, dict)):
            raise UssSlamError(
                f"net_config must be a yaml file or a mapping with a _target_, got {net_config!r}"
            )
        int8 = _value(cfg, "int8")
        if not isinstance(int8, bool):
            raise UssSlamError(f"int8 must be true or false, got {int8!r}")
        root = _text(cfg, "calibration.root")
        if int8 and root is None:
            raise UssSlamError(
                "int8=true needs calibration.root=<TUM RGB-D folder of target frames>"
            )
        out = _text(cfg, "out")
        if out is None:
            name = _text(cfg, "name")
            if name is None:
                name = run_name(ckpt_path) or ckpt_path.stem
                if head != "main":
                    name = f"{name}_{head}"
            out = str(Path(_text(cfg, "out_dir", optional=False)) / f"{name}.onnx")
        return cls(
            ckpt_path=ckpt_path,
            out=Path(out),
            head=head,
            opset=opset,
            net_config=net_config,
            experiment=_text(cfg, "experiment"),
            dynamic_classes=tuple(dynamic),
            trace_size=_value(cfg, "trace_size"),
            verify_size=_value(cfg, "verify_size"),
            max_logit_diff=_number(cfg, "max_logit_diff", 0.0),
            min_label_agreement=_number(cfg, "min_label_agreement", 0.0, 1.0),
            num_threads=_int(cfg, "num_threads", optional=True),
            calibration_root=Path(root) if int8 and root is not None else None,
            calibration_frames=_int(cfg, "calibration.frames"),  # type: ignore[arg-type]
        )


def run(cfg: DictConfig) -> ExportResult:
    """``uss-export`` without Hydra's wrapper (tests call it with a composed config)."""
    options = ExportOptions.from_config(cfg)
    check_options(
        options.out,
        options.opset,
        options.trace_size,
        options.verify_size,
        int8=options.calibration_root is not None,
    )
    # Read the calibration frames before the checkpoint: a bad folder must fail before
    # anything is written.
    calibration = None
    if options.calibration_root is not None:
        calibration = CalibrationSet.read(options.calibration_root, options.calibration_frames)
    if options.num_threads:
        torch.set_num_threads(options.num_threads)
    return export_checkpoint(
        options.ckpt_path,
        options.out,
        head=options.head,
        opset=options.opset,
        net_cfg=options.net_config,
        experiment=options.experiment,
        dynamic_classes=options.dynamic_classes,
        trace_size=options.trace_size,
        verify_size=options.verify_size,
        max_logit_diff=options.max_logit_diff,
        min_label_agreement=options.min_label_agreement,
        calibration=calibration,
        threads=options.num_threads,
    )


@hydra.main(version_base="1.3", config_path="../configs", config_name="export")
def app(cfg: DictConfig) -> None:
    """The Hydra task: export, then print what was written."""
    result = hydra_task(PROG, run, cfg)
    if result is None:  # a multirun job that failed: the other jobs go on
        return
    v = result.verify
    print(
        f"uss-export: wrote {result.path} (verified at {v['verify_size']}: max |logit diff| "
        f"{v['max_abs_logit_diff']:.2e}, label agreement {v['label_agreement']:.5f}); "
        f"report {result.verify_path}"
    )
    if result.int8_path is not None:
        q = v["int8"]
        print(
            f"uss-export: wrote {result.int8_path} ({q['speedup']:.2f}x faster than FP32 at "
            f"{q['frame_size']}, label agreement with FP32 {q['label_agreement_vs_fp32']:.4f})"
        )


def main() -> None:
    """``uss-export``: every user error is one line on stderr and exit code 1, the errors Hydra
    raises while composing the config (an unknown key, bad override syntax, an output folder it
    cannot create) included."""
    run_hydra_app(PROG, app)


if __name__ == "__main__":
    main()

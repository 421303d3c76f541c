"""``uss-export``: a ``uss-train`` checkpoint -> a self-describing, verified ONNX segmenter.

Examples::

    uss-export ckpt_path=outputs/train/runs/demo/<time>/checkpoints/last.ckpt
    uss-export ckpt_path=PATH name=demo_aux head=aux out=/tmp/demo_aux.onnx
    uss-export ckpt_path=PATH int8=true calibration.root=outputs/demo/data/slam/walking_xyz
    uss-export ckpt_path=B001.ckpt 'ensemble=[B005.ckpt,B009.ckpt]'   # mean of three models

Every option is checked first (types, opset, sizes), then the calibration frames are read (with
``int8=true``), then the checkpoint; only then is anything written. A bad input ends with one
line on stderr naming the key or file, and exit code 1.
"""

from __future__ import annotations

import re
import sys
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import hydra
import torch
from omegaconf import DictConfig, OmegaConf

from uss_slam.core.cli import hydra_task, run_hydra_app, warning
from uss_slam.core.errors import UssSlamError
from uss_slam.core.onnx_contract import HEADS
from uss_slam.core.paths import (
    input_file,
    input_folder,
    naming,
    naming_roots,
    output_file,
    output_folder,
)
from uss_slam.core.schema import MAX_THREADS, check, ranged, unused_settings
from uss_slam.export.checkpoint import run_name
from uss_slam.export.onnx import check_options, export_checkpoint
from uss_slam.export.outputs import ExportResult
from uss_slam.export.quantize import CalibrationSet

PROG = "uss-export"

# OmegaConf reads Optional[...] (not X | None) in a dataclass schema.
# ruff: noqa: UP045


@dataclass
class CalibrationSchema:
    root: Optional[str] = ranged(None, text=True)
    frames: int = ranged(16, min=1)


@dataclass
class ExportSchema:
    """The keys of ``configs/export.yaml`` (see that file for each), their types and ranges:
    checked by :func:`uss_slam.core.schema.check` before anything is read; a bad value or an
    unknown key is one line ``<key>: expected ..., got ...``. Rules across keys and against the
    installed torch / onnxruntime (the opset range, the two sizes, int8's calibration folder)
    are :func:`uss_slam.export.onnx.check_options`' and :meth:`ExportOptions.from_config`'s."""

    ckpt_path: Optional[str] = ranged(None, text=True)
    ensemble: list[str] = ranged(default_factory=list, text=True)
    name: Optional[str] = ranged(None, text=True)
    out_dir: str = ranged("exports", text=True)
    out: Optional[str] = ranged(None, text=True)
    head: str = ranged("main", choices=HEADS)
    opset: int = 17
    net_config: Any = None
    experiment_name: Optional[str] = ranged(None, text=True)
    dynamic_classes: list[str] = field(default_factory=lambda: ["person"])
    trace_size: Any = field(default_factory=lambda: [97, 129])
    verify_size: Any = field(default_factory=lambda: [120, 160])
    max_logit_diff: Optional[float] = ranged(None, gt=0)
    min_label_agreement: Optional[float] = ranged(None, gt=0, max=1)
    num_threads: Optional[int] = ranged(None, min=1, max=MAX_THREADS)
    int8: bool = False
    calibration: CalibrationSchema = ranged(default_factory=CalibrationSchema, needs="int8")


def _value(cfg: DictConfig, key: str) -> Any:
    value = OmegaConf.select(cfg, key, default=None)
    return OmegaConf.to_container(value) if OmegaConf.is_config(value) else value


@dataclass(frozen=True)
class ExportOptions:
    """``configs/export.yaml``, type-checked (see that file for each key)."""

    ckpt_path: Path
    ensemble: tuple[Path, ...]
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
        plain = {k: v for k, v in cfg.items() if k != "hydra"}
        check(OmegaConf.create(plain), ExportSchema)
        for line in unused_settings(OmegaConf.create(plain), ExportSchema):
            warning(line)  # calibration.* without int8=true: accepted, changes nothing
        ckpt = _value(cfg, "ckpt_path")
        if ckpt is None or ckpt == "":
            raise UssSlamError("ckpt_path=PATH is required (a uss-train .ckpt)")
        ckpt_path = input_file(str(ckpt), "ckpt_path", "expected a uss-train checkpoint (.ckpt)")
        ensemble = _ensemble(ckpt_path, _value(cfg, "ensemble"))
        head = _value(cfg, "head")
        net_config = _value(cfg, "net_config")
        if net_config is not None and not isinstance(net_config, (str, dict)):
            raise UssSlamError(
                f"net_config: expected a yaml file or a mapping with a _target_, got {net_config!r}"
            )
        int8 = bool(_value(cfg, "int8"))
        root = _value(cfg, "calibration.root")
        if int8 and root is None:
            raise UssSlamError(
                "int8=true needs calibration.root=<TUM RGB-D folder of target frames>"
            )
        out = _value(cfg, "out")
        out_key = "out" if out is not None else "out_dir" if _value(cfg, "name") is None else "name"
        if out is None:
            name = _value(cfg, "name")
            if name is not None and ("/" in str(name) or str(name) in (".", "..")):
                raise UssSlamError(
                    f"name={name}: expected a file name without '/' (the model is written into "
                    "out_dir; out=PATH writes it elsewhere)"
                )
            if name is None:
                name = run_name(ckpt_path) or ckpt_path.stem
                if ensemble:
                    name = f"{name}_ensemble{len(ensemble) + 1}"
                if head != "main":
                    name = f"{name}_{head}"
            out = str(Path(str(_value(cfg, "out_dir"))) / f"{name}.onnx")
        if out_key == "out_dir":
            output_folder(Path(str(out)).parent, "out_dir")
        output_file(str(out), out_key, "expected an .onnx file to write")
        if int8:
            input_folder(str(root), "calibration.root", "expected a TUM RGB-D folder with rgb.txt")
        max_diff, agreement = _value(cfg, "max_logit_diff"), _value(cfg, "min_label_agreement")
        experiment = _value(cfg, "experiment_name")
        return cls(
            ckpt_path=ckpt_path,
            ensemble=ensemble,
            out=Path(str(out)),
            head=head,
            opset=_value(cfg, "opset"),
            net_config=net_config,
            experiment=None if experiment is None else str(experiment),
            dynamic_classes=tuple(_value(cfg, "dynamic_classes")),
            trace_size=_value(cfg, "trace_size"),
            verify_size=_value(cfg, "verify_size"),
            max_logit_diff=None if max_diff is None else float(max_diff),
            min_label_agreement=None if agreement is None else float(agreement),
            num_threads=_value(cfg, "num_threads"),
            calibration_root=Path(str(root)) if int8 and root is not None else None,
            calibration_frames=_value(cfg, "calibration.frames"),
        )


def _ensemble(ckpt_path: Path, items: list[str]) -> tuple[Path, ...]:
    """``ensemble``'s checkpoints, each a readable file and none of them ``ckpt_path`` or another
    item under a second spelling (the schema refuses an item written twice)."""
    paths = tuple(
        input_file(str(item), "ensemble", "expected a uss-train checkpoint (.ckpt)")
        for item in items
    )
    seen = {ckpt_path.resolve(): "ckpt_path"}
    for path in paths:
        if path.resolve() in seen:
            raise UssSlamError(
                f"ensemble: {path} is the same file as {seen[path.resolve()]}: an ensemble "
                "averages different checkpoints"
            )
        seen[path.resolve()] = f"ensemble item {path}"
    return paths


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
        root = str(options.calibration_root)
        with naming_roots({"root": root}, "calibration"):  # a bad frame names the key too
            calibration = CalibrationSet.read(root, options.calibration_frames)
    if options.num_threads:
        torch.set_num_threads(options.num_threads)
    with ExitStack() as names:  # ckpt_path=<file>: not a readable checkpoint
        names.enter_context(naming("ckpt_path", options.ckpt_path))
        for path in options.ensemble:
            names.enter_context(naming("ensemble", path))
        return _export(options, calibration)


def _export(options: ExportOptions, calibration: CalibrationSet | None) -> ExportResult:
    """:func:`run` once the options are checked."""
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
        ensemble=options.ensemble,
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


EXPERIMENT_OVERRIDE = re.compile(r"^[+~]*experiment=(.*)$")
"""``experiment=NAME`` on the command line: Hydra reads it as a choice of the ``experiment``
config group (uss-train's presets, in the same config folder), never as the model's name."""


def main() -> None:
    """``uss-export``: every user error is one line on stderr and exit code 1, the errors Hydra
    raises while composing the config (an unknown key, bad override syntax, an output folder it
    cannot create) included."""
    for argument in sys.argv[1:]:
        found = EXPERIMENT_OVERRIDE.match(argument)
        if found:
            print(
                f"{PROG}: error: {argument}: the experiment name stored in the model is "
                f"experiment_name={found.group(1) or 'NAME'} (experiment= selects a uss-train "
                "preset)",
                file=sys.stderr,
            )
            sys.exit(1)
    run_hydra_app(PROG, app)


if __name__ == "__main__":
    main()

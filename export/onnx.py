"""Segmenter -> verified, self-describing ONNX model (+ INT8), written atomically.

Only the segmenter is exported (``segmenter.*`` weights; the discriminators stay behind), wrapped
(:class:`~uss_slam.export.wrapper.SegmenterExport`) so that the graph follows the contract of
:mod:`uss_slam.core.onnx_contract`: uint8 NHWC RGB in; ``logits`` (N, C, H, W) at the input
size and uint8 ``labels`` (N, H, W) out; normalisation and layout change inside the graph;
metadata in ``metadata_props``.

Every option is checked and the output folder proven writable before the trace starts. The
model is written under a temporary name in the target folder, checked (``onnx.checker``),
verified against PyTorch eager at a size different from the trace size, optionally quantised
to INT8, and only then are ``<name>.onnx``, ``<name>.int8.onnx`` and ``<name>.verify.json``
renamed into place together. A failed check leaves earlier files in place, writes
``<name>.verify.failed.json`` and raises :class:`ExportVerificationError`.
"""

from __future__ import annotations

import functools
import io
import logging
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import onnx
import onnxruntime as ort
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from uss_slam.core.classes import DYNAMIC_CLASSES
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import (
    StagedFiles,
    check_writable,
    lock_held,
    output_lock,
    stale_temporaries,
    write_json_atomic,
)
from uss_slam.core.normalization import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.core.onnx_contract import (
    HEADS,
    INPUT_NAME,
    OUTPUT_LABELS,
    OUTPUT_LOGITS,
    SegmenterMetadata,
)
from uss_slam.export.checkpoint import load_checkpoint
from uss_slam.export.outputs import (
    FAILED_SUFFIX,
    INT8_SUFFIX,
    VERIFY_SUFFIX,
    ExportResult,
    check_output_path,
    sidecar,
)
from uss_slam.export.quantize import CalibrationSet, log_int8, write_int8
from uss_slam.export.verify import (
    DEFAULT_VERIFY_SIZE,
    ExportVerificationError,
    failure_message,
    verification_images,
    verify_model,
)
from uss_slam.export.wrapper import SegmenterExport

log = logging.getLogger(__name__)

DEFAULT_OPSET = 17
DEFAULT_TRACE_SIZE = (97, 129)
"""(H, W) of the example input the exporter traces with (any size works at run time)."""
MIN_OPSET = 11
"""Lowest opset of the graph: bilinear resizing with ``align_corners=True`` needs Resize-11."""
MIN_INT8_OPSET = 13
"""Lowest opset of the INT8 model: per-channel weight scales need DequantizeLinear-13."""


def project_version() -> str:
    try:
        return version("uss-slam")
    except PackageNotFoundError:  # running from a source tree without installing
        return "unknown"


# ---------------------------------------------------------------------------- option checks


class _OpsetProbe(nn.Module):
    """The graph's operators that depend most on the opset: align-corners Resize, ArgMax and
    the cast to uint8."""

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        y = F.interpolate(x, size=(5, 5), mode="bilinear", align_corners=True)
        return y, y.argmax(dim=1).to(torch.uint8)


def _opset_works(opset: int) -> bool:
    """Whether this install's ``torch.onnx`` (TorchScript exporter) writes ``opset`` without
    complaint and onnxruntime loads the result (a tiny probe model, in memory)."""
    buffer = io.BytesIO()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            probe = (_OpsetProbe(), (torch.zeros(1, 2, 3, 3),), buffer)
            torch.onnx.export(*probe, dynamo=False, opset_version=opset)
        # Above its highest opset the exporter only warns, and writes a model anyway.
        if any(not issubclass(w.category, DeprecationWarning) for w in caught):
            return False
        ort.InferenceSession(buffer.getvalue(), providers=["CPUExecutionProvider"])
    except Exception:  # torch and onnxruntime refuse with unrelated exception types
        return False
    return True


@functools.cache
def supported_opsets() -> range:
    """The opsets this install exports the graph at and onnxruntime runs: from
    :data:`MIN_OPSET` up to the first one refused (found with a tiny probe model, once per
    process; the scan stops at the first refusal because torch dumps its graph to stdout when
    it raises for an opset beyond its tables)."""
    top = MIN_OPSET - 1
    while top < onnx.defs.onnx_opset_version() and _opset_works(top + 1):
        top += 1
    return range(MIN_OPSET, top + 1)


def check_opset(opset: int) -> int:
    """``opset`` if this install exports and runs the graph at it, else a one-line error."""
    if isinstance(opset, bool) or not isinstance(opset, int):
        raise UssSlamError(f"opset must be an integer, got {opset!r}")
    ok = supported_opsets()
    if opset not in ok:
        accepted = f"{ok.start}..{ok.stop - 1}" if ok else "none"
        raise UssSlamError(
            f"opset {opset} is not supported: torch {torch.__version__} exports and onnxruntime "
            f"{ort.__version__} runs this graph at opset {accepted}"
        )
    return opset


MIN_VERIFY_SIDE = 32
"""Smallest height and width (pixels) of the verification images: at output stride 8 that is
4 x 4 logit cells upsampled to the image, the least where per-pixel logits and labels of the
ONNX model and the checkpoint can disagree in more than one value."""


def check_size(key: str, value: Sequence[int]) -> tuple[int, int]:
    """``(H, W)`` of two positive integers, else a one-line error naming ``key``."""
    items = list(value) if isinstance(value, (list, tuple)) else None
    if (
        items is None
        or len(items) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in items)
    ):
        raise UssSlamError(f"{key} must be [H, W], two positive integers; got {value!r}")
    if max(items) > MAX_SIDE:  # bounded work: a frame of this size is no export check
        raise UssSlamError(
            f"{key} must be [H, W], each side at most {MAX_SIDE} px (a frame); got {value!r}"
        )
    return items[0], items[1]


MAX_SIDE = 8192
"""The longest side of a trace or verification frame, px (8K video's width)."""


def check_options(
    out: str | Path,
    opset: int,
    trace_size: Sequence[int],
    verify_size: Sequence[int],
    int8: bool = False,
) -> tuple[Path, tuple[int, int], tuple[int, int]]:
    """Every export option checked before anything is loaded or written (``int8``: an INT8
    model is requested too)."""
    out = Path(out)
    check_output_path(out)
    trace = check_size("trace_size", trace_size)
    verify = check_size("verify_size", verify_size)
    if min(verify) < MIN_VERIFY_SIDE:
        raise UssSlamError(
            f"verify_size must be at least [{MIN_VERIFY_SIDE}, {MIN_VERIFY_SIDE}], got "
            f"{list(verify)}: the segmenters' output stride is 8, so a smaller image gives "
            "fewer than 4x4 logit cells and the comparison would prove almost nothing"
        )
    if trace == verify:
        raise UssSlamError(f"verify_size must differ from trace_size ({trace})")
    check_opset(opset)
    if int8 and opset < MIN_INT8_OPSET:
        raise UssSlamError(
            f"opset {opset} is too old for int8=true: per-channel INT8 weights need opset "
            f">= {MIN_INT8_OPSET}"
        )
    return out, trace, verify


# ---------------------------------------------------------------------------- export


def write_onnx(
    wrapper: SegmenterExport,
    path: Path,
    metadata: SegmenterMetadata,
    opset: int,
    trace_size: tuple[int, int],
) -> None:
    """Trace ``wrapper`` at ``trace_size`` into ``path`` with dynamic N, H, W and the contract's
    names, then store ``metadata`` in ``metadata_props``."""
    example = torch.from_numpy(verification_images(trace_size, batch=1, seed=1))
    with warnings.catch_warnings(), torch.no_grad():
        # The TorchScript exporter: the torch.export one needs onnxscript (not installed).
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            wrapper,
            (example,),
            str(path),
            dynamo=False,
            opset_version=opset,
            input_names=[INPUT_NAME],
            output_names=[OUTPUT_LOGITS, OUTPUT_LABELS],
            dynamic_axes={
                INPUT_NAME: {0: "N", 1: "H", 2: "W"},
                OUTPUT_LOGITS: {0: "N", 2: "H", 3: "W"},
                OUTPUT_LABELS: {0: "N", 1: "H", 2: "W"},
            },
        )
    model = onnx.load(str(path))
    onnx.helper.set_model_props(model, metadata.to_props())
    model.doc_string = (
        f"uss-slam segmenter ({metadata.experiment}, head {metadata.head}): uint8 NHWC RGB "
        "image -> logits (N,C,H,W), labels (N,H,W) uint8; see exports/README.md"
    )
    model.producer_name = "uss-export"
    onnx.save(model, str(path))


def remove_stale_temporaries(out: Path) -> list[Path]:
    """Remove the temporary files an export to ``out`` that was killed (kill -9: no cleanup ran)
    left beside it: ``.<name>.<random>.tmp`` of the model and each sidecar. Called with ``out``'s
    lock held, so that no other export is writing them; a sidecar that is itself locked as the
    output of another export (an ``out`` named ``<name>.int8.onnx``) is left alone."""
    removed = []
    for final in (out, *(sidecar(out, s) for s in (VERIFY_SUFFIX, FAILED_SUFFIX, INT8_SUFFIX))):
        if final != out and lock_held(final):
            continue
        for path in stale_temporaries(final):
            path.unlink(missing_ok=True)
            log.info("removed %s (left by an export that was killed)", path)
            removed.append(path)
    return removed


def export_segmenter(
    segmenter: nn.Module,
    out: str | Path,
    metadata: SegmenterMetadata,
    *,
    opset: int = DEFAULT_OPSET,
    trace_size: tuple[int, int] = DEFAULT_TRACE_SIZE,
    verify_size: tuple[int, int] = DEFAULT_VERIFY_SIZE,
    max_logit_diff: float | None = None,
    min_label_agreement: float | None = None,
    calibration: CalibrationSet | None = None,
    threads: int | None = None,
    members: Sequence[nn.Module] = (),
) -> ExportResult:
    """Export ``segmenter`` (``forward`` -> ``.aux`` / ``.main`` logits) to ``out``, verified;
    with ``members``, the ensemble of ``segmenter`` and them (their mean probabilities, see
    :class:`~uss_slam.export.wrapper.SegmenterExport`).

    With ``calibration`` also ``<name>.int8.onnx`` (see :mod:`uss_slam.export.quantize`;
    ``threads`` for its timing); without it, an ``<name>.int8.onnx`` of an earlier export is
    removed, so the FP32 and INT8 models next to each other always come from one checkpoint.
    Raises :class:`ExportVerificationError` (after writing ``<name>.verify.failed.json``) when
    ``onnx.checker`` or the comparison with PyTorch fails; ``out`` and its sidecars are then
    untouched. ``out`` is locked while it is written (:func:`~uss_slam.core.files.output_lock`:
    a second export to the same name stops with :class:`~uss_slam.core.errors.OutputInUseError`);
    a full disk is a :class:`~uss_slam.core.errors.NoSpaceError` that leaves the earlier files.
    """
    out, trace_size, verify_size = check_options(
        out, opset, trace_size, verify_size, int8=calibration is not None
    )
    wrapper = SegmenterExport(
        segmenter, metadata.head, metadata.mean, metadata.std, members=members
    ).eval()
    check_writable(out.parent)
    verify_path = sidecar(out, VERIFY_SUFFIX)
    int8_out = sidecar(out, INT8_SUFFIX)
    started = time.perf_counter()
    with output_lock(out), StagedFiles() as staged:
        remove_stale_temporaries(out)
        tmp = staged.path(out)
        write_onnx(wrapper, tmp, metadata, opset, trace_size)
        report: dict[str, Any] = {
            "model": out.name,
            "head": metadata.head,
            "experiment": metadata.experiment,
            "checkpoint_sha256": metadata.checkpoint_sha256,
            "opset": opset,
            "trace_size": list(trace_size),
            "export_seconds": round(time.perf_counter() - started, 3),
            "versions": {
                "uss_slam": metadata.version,
                "torch": torch.__version__,
                "onnx": onnx.__version__,
                "onnxruntime": ort.__version__,
            },
        }
        try:
            onnx.checker.check_model(str(tmp), full_check=True)
            report["checker"] = "ok"
        except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError) as error:
            report["checker"] = f"failed: {error}"
            report["ok"] = False
        if "ok" not in report:
            report.update(
                verify_model(
                    tmp,
                    wrapper,
                    verify_size,
                    max_logit_diff=max_logit_diff,
                    min_label_agreement=min_label_agreement,
                )
            )
        if not report["ok"]:
            failed = sidecar(out, FAILED_SUFFIX)
            write_json_atomic(failed, report)
            raise ExportVerificationError(failure_message(out, report, failed))
        if calibration is not None:
            figures = write_int8(
                tmp,
                staged.path(int8_out),
                calibration.calibration,
                calibration.evaluation,
                threads=threads,
            )
            figures["model"] = int8_out.name
            figures["calibration_root"] = str(calibration.root)
            report["int8"] = figures
        staged.write_json(verify_path, report)
        stale = [sidecar(out, FAILED_SUFFIX)] + ([int8_out] if calibration is None else [])
        staged.commit(remove=stale)
    log.info(
        "wrote %s (max |logit diff| %.2e, label agreement %.5f at %s)",
        out,
        report["max_abs_logit_diff"],
        report["label_agreement"],
        verify_size,
    )
    if calibration is not None:
        log_int8(int8_out, report["int8"])
    return ExportResult(
        path=out,
        verify_path=verify_path,
        verify=report,
        metadata=metadata,
        int8_path=int8_out if calibration is not None else None,
    )


def export_checkpoint(
    ckpt_path: str | Path,
    out: str | Path,
    *,
    head: str = "main",
    opset: int = DEFAULT_OPSET,
    net_cfg: Mapping[str, Any] | str | Path | None = None,
    experiment: str | None = None,
    dynamic_classes: Sequence[str] = DYNAMIC_CLASSES,
    trace_size: tuple[int, int] = DEFAULT_TRACE_SIZE,
    verify_size: tuple[int, int] = DEFAULT_VERIFY_SIZE,
    max_logit_diff: float | None = None,
    min_label_agreement: float | None = None,
    calibration: CalibrationSet | None = None,
    threads: int | None = None,
    prepare: Callable[[nn.Module], object] | None = None,
    ensemble: Sequence[str | Path] = (),
) -> ExportResult:
    """Export the segmenter of a ``uss-train`` checkpoint to ``out`` (see
    :func:`~uss_slam.export.checkpoint.load_checkpoint` and :func:`export_segmenter`);
    ``experiment`` defaults to the training run's ``run_name``. ``prepare`` is applied to the
    loaded segmenter before the trace (e.g. :func:`uss_slam.train.precise_bn.adabn`: target
    BatchNorm statistics); the metadata's checkpoint hash stays the checkpoint's.

    ``ensemble``: further checkpoints (same classes, any architecture ``net_cfg`` or their runs
    give) whose probabilities are averaged with this one's in one graph (FDA's multi-band
    ensemble); ``experiment`` then defaults to the run names joined by ``+`` and the checkpoint
    hash to every file's hash, comma-separated, in order."""
    if head not in HEADS:
        raise UssSlamError(f"head must be one of {HEADS}, got {head!r}")
    check_options(out, opset, trace_size, verify_size, int8=calibration is not None)
    loaded = load_checkpoint(ckpt_path, net_cfg)
    members = [load_checkpoint(path, net_cfg) for path in ensemble]
    for path, member in zip(ensemble, members, strict=True):
        if member.class_names != loaded.class_names:
            raise DataFormatError(
                path,
                f"its classes ({', '.join(member.class_names)}) differ from ckpt_path's "
                f"({', '.join(loaded.class_names)}): an ensemble averages the same classes",
            )
    for each in (loaded, *members):
        if prepare is not None:
            prepare(each.segmenter)
    unknown = [c for c in dynamic_classes if c not in loaded.class_names]
    if unknown:
        raise UssSlamError(f"dynamic_classes {unknown} are not among {loaded.class_names}")
    metadata = SegmenterMetadata(
        class_names=loaded.class_names,
        dynamic_classes=tuple(dynamic_classes),
        mean=IMAGENET_MEAN,
        std=IMAGENET_STD,
        head=head,
        experiment=experiment or "+".join(m.experiment for m in (loaded, *members)),
        checkpoint_sha256=",".join(m.sha256 for m in (loaded, *members)),
        version=project_version(),
    )
    return export_segmenter(
        loaded.segmenter,
        out,
        metadata,
        opset=opset,
        trace_size=trace_size,
        verify_size=verify_size,
        max_logit_diff=max_logit_diff,
        min_label_agreement=min_label_agreement,
        calibration=calibration,
        threads=threads,
        members=[m.segmenter for m in members],
    )

"""``uss-export``: a ``uss-train`` checkpoint -> a self-describing, verified ONNX segmenter.

Examples::

    uss-export ckpt_path=outputs/train/runs/demo/<time>/checkpoints/last.ckpt
    uss-export ckpt_path=PATH name=demo_aux head=aux out=/tmp/demo_aux.onnx
    uss-export ckpt_path=PATH int8=true calibration.root=outputs/demo/data/slam/walking_xyz

Only the segmenter is exported (``segmenter.*`` weights; the discriminators stay behind), wrapped
so that the graph follows the contract of :mod:`uss_slam.core.onnx_contract`: uint8 NHWC RGB
in; ``logits`` (N, C, H, W) at the input size and uint8 ``labels`` (N, H, W) out; normalisation
and layout change inside the graph; metadata in ``metadata_props``.

Every model is written to a temporary file in the target folder, checked (``onnx.checker``),
verified against PyTorch eager at a size different from the trace size (max |logit difference|
<= :data:`MAX_LOGIT_DIFF`, label agreement >= :data:`MIN_LABEL_AGREEMENT`) and only then renamed
over ``out``; the result goes to ``<name>.verify.json``. A failed check leaves earlier files in
place, writes ``<name>.verify.failed.json`` and raises :class:`ExportVerificationError` (exit 1).
"""

from __future__ import annotations

import json
import logging
import os
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import hydra
import numpy as np
import onnx
import onnxruntime as ort
import torch
import torch.nn.functional as F
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from torch import Tensor, nn

from uss_slam.core.classes import CLASS_NAMES, DYNAMIC_CLASSES
from uss_slam.core.cli import exit_on_user_error
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import file_sha256
from uss_slam.core.onnx_contract import (
    HEADS,
    INPUT_NAME,
    OUTPUT_LABELS,
    OUTPUT_LOGITS,
    SegmenterMetadata,
)
from uss_slam.datasets.transforms import IMAGENET_MEAN, IMAGENET_STD
from uss_slam.models.deeplab import DeepLabV2

log = logging.getLogger(__name__)

MAX_LOGIT_DIFF = 1e-4
"""Largest accepted |onnxruntime - PyTorch| logit difference in verification."""
MIN_LABEL_AGREEMENT = 0.999
"""Smallest accepted fraction of equal labels (onnxruntime vs PyTorch) in verification."""
DEFAULT_OPSET = 17
DEFAULT_TRACE_SIZE = (97, 129)
"""(H, W) of the example input the exporter traces with (any size works at run time)."""
DEFAULT_VERIFY_SIZE = (120, 160)
"""(H, W) of the verification batch; must differ from the trace size."""
VERIFY_BATCH = 2


class ExportVerificationError(UssSlamError):
    """The exported model does not reproduce PyTorch (or fails ``onnx.checker``)."""


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_checkpoint` / :func:`export_segmenter` wrote."""

    path: Path
    """The verified ONNX model."""
    verify_path: Path
    """``<name>.verify.json`` next to it."""
    verify: dict[str, Any]
    """The content of ``verify_path``."""
    metadata: SegmenterMetadata
    int8_path: Path | None = None
    """``<name>.int8.onnx`` when INT8 was requested (its figures are in ``verify["int8"]``)."""


class SegmenterExport(nn.Module):
    """The exported graph: uint8 NHWC RGB -> (logits at input size, uint8 labels).

    ``image`` ``(N, H, W, 3)`` uint8 -> float, ``/255``, ``(x - mean) / std`` per RGB channel,
    NCHW -> the chosen head's logits, bilinearly upsampled (``align_corners=True``, as the
    training losses and validation) -> ``logits`` ``(N, C, H, W)`` float32 and
    ``labels = argmax_C(logits)`` ``(N, H, W)`` uint8.
    """

    def __init__(
        self,
        segmenter: nn.Module,
        head: str = "main",
        mean: Sequence[float] = IMAGENET_MEAN,
        std: Sequence[float] = IMAGENET_STD,
    ) -> None:
        super().__init__()
        if head not in HEADS:
            raise UssSlamError(f"head must be one of {HEADS}, got {head!r}")
        self.segmenter = segmenter
        self.head = head
        # Scaled by 255 so the graph needs one subtraction and one division.
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1) * 255)
        self.register_buffer("std", torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1) * 255)

    def forward(self, image: Tensor) -> tuple[Tensor, Tensor]:
        x = image.permute(0, 3, 1, 2).to(torch.float32)
        x = (x - self.mean) / self.std
        out = getattr(self.segmenter(x), self.head)
        logits = F.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=True)
        return logits, logits.argmax(dim=1).to(torch.uint8)


# ---------------------------------------------------------------------------- checkpoints


def project_version() -> str:
    try:
        return version("uss-slam")
    except PackageNotFoundError:  # running from a source tree without installing
        return "unknown"


def run_config_path(ckpt_path: Path) -> Path:
    """``<run_dir>/.hydra/config.yaml`` of a checkpoint in ``<run_dir>/checkpoints/``."""
    return ckpt_path.resolve().parent.parent / ".hydra" / "config.yaml"


@dataclass(frozen=True)
class LoadedCheckpoint:
    segmenter: DeepLabV2
    class_names: tuple[str, ...]
    experiment: str
    sha256: str
    iteration: int | None
    net_config: dict[str, Any]


def _net_config(
    ckpt_path: Path, net_cfg: Mapping[str, Any] | str | Path | None
) -> tuple[DictConfig, str | None]:
    """The segmenter's Hydra config (``_target_`` node) and the training run's name."""
    run_cfg_path = run_config_path(ckpt_path)
    run_cfg = OmegaConf.load(run_cfg_path) if run_cfg_path.is_file() else None
    run_name = None
    if isinstance(run_cfg, DictConfig):
        run_name = run_cfg.get("run_name")
    if net_cfg is not None:
        if isinstance(net_cfg, (str, Path)):
            path = Path(net_cfg)
            if not path.is_file():
                raise DataFormatError(path, "net config file not found")
            node = OmegaConf.load(path)
        elif isinstance(net_cfg, DictConfig):
            node = net_cfg
        else:
            node = OmegaConf.create(dict(net_cfg))
        if not isinstance(node, DictConfig) or "_target_" not in node:
            raise UssSlamError(f"net config {net_cfg} has no _target_ (see configs/model/net/)")
        return node, run_name
    if run_cfg is None:
        raise DataFormatError(
            run_cfg_path,
            f"no training config for {ckpt_path} (expected the run's .hydra/config.yaml next "
            "to its checkpoints/ folder); pass net_config=<yaml of configs/model/net/>",
        )
    node = OmegaConf.select(run_cfg, "model.net")
    if not isinstance(node, DictConfig) or "_target_" not in node:
        raise DataFormatError(run_cfg_path, "expected a model.net node with a _target_")
    return node, run_name


def load_checkpoint(
    ckpt_path: str | Path, net_cfg: Mapping[str, Any] | str | Path | None = None
) -> LoadedCheckpoint:
    """Build the segmenter of a ``uss-train`` checkpoint (eval mode, CPU).

    The architecture comes from the training run's ``.hydra/config.yaml`` (``model.net``) unless
    ``net_cfg`` (a mapping or a yaml file with a ``_target_``) overrides it; weights are the
    checkpoint's ``segmenter.*`` entries, loaded strictly (no initial weights are read or
    downloaded).
    """
    ckpt_path = Path(ckpt_path)
    if not ckpt_path.is_file():
        raise DataFormatError(ckpt_path, "checkpoint not found")
    try:
        blob = torch.load(ckpt_path, map_location="cpu", weights_only=True)
    except Exception as error:  # unpickling errors share no base class
        raise DataFormatError(
            ckpt_path, f"not a readable checkpoint ({type(error).__name__}: {error})"
        ) from error
    if not isinstance(blob, dict) or not isinstance(blob.get("state_dict"), dict):
        raise DataFormatError(ckpt_path, "expected a uss-train checkpoint with a state_dict")
    state = {
        k.removeprefix("segmenter."): v
        for k, v in blob["state_dict"].items()
        if k.startswith("segmenter.")
    }
    if not state:
        raise DataFormatError(ckpt_path, "checkpoint state_dict has no 'segmenter.*' entries")
    hparams = blob.get("hyper_parameters") or {}
    class_names = tuple(hparams.get("class_names") or CLASS_NAMES)

    node, run_name = _net_config(ckpt_path, net_cfg)
    node = OmegaConf.create(OmegaConf.to_container(node, resolve=True))
    # The checkpoint holds every weight: never read (or download) initial weights.
    for key in ("weights_path", "backbone_weights"):
        if key in node:
            node[key] = None
    segmenter = instantiate(node)
    if not isinstance(segmenter, DeepLabV2):
        raise DataFormatError(
            ckpt_path, f"net config builds {type(segmenter).__name__}, expected DeepLabV2"
        )
    if segmenter.num_classes != len(class_names):
        raise DataFormatError(
            ckpt_path,
            f"net config has {segmenter.num_classes} classes, checkpoint {len(class_names)}",
        )
    try:
        segmenter.load_state_dict(state, strict=True)
    except RuntimeError as error:
        raise DataFormatError(
            ckpt_path, f"segmenter weights do not fit the net config: {error}".splitlines()[0]
        ) from error
    segmenter.eval()
    return LoadedCheckpoint(
        segmenter=segmenter,
        class_names=class_names,
        experiment=str(run_name) if run_name else ckpt_path.stem,
        sha256=file_sha256(ckpt_path),
        iteration=blob.get("iteration"),
        net_config=OmegaConf.to_container(node),  # type: ignore[arg-type]
    )


# ---------------------------------------------------------------------------- export


def verification_images(
    size: tuple[int, int], batch: int = VERIFY_BATCH, seed: int = 0
) -> np.ndarray:
    """``(batch, H, W, 3)`` uint8 test images: smooth random colour fields plus pixel noise
    (structure at several scales, so labels are not a single class and ties are rare)."""
    rng = np.random.default_rng(seed)
    h, w = size
    coarse = torch.from_numpy(rng.uniform(0, 255, (batch, 3, max(2, h // 12), max(2, w // 12))))
    smooth = F.interpolate(coarse, size=size, mode="bilinear", align_corners=False).numpy()
    noisy = smooth + rng.normal(0, 12, smooth.shape)
    return np.clip(noisy, 0, 255).round().astype(np.uint8).transpose(0, 2, 3, 1).copy()


def make_session(path: Path, threads: int | None = None) -> ort.InferenceSession:
    options = ort.SessionOptions()
    if threads:
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)


def sidecar(out: Path, suffix: str) -> Path:
    """``exports/x.onnx`` -> ``exports/x<suffix>`` (e.g. ``.verify.json``)."""
    return out.with_name(out.name.removesuffix(".onnx") + suffix)


def verify_model(
    path: Path,
    wrapper: SegmenterExport,
    size: tuple[int, int],
    batch: int = VERIFY_BATCH,
    max_logit_diff: float | None = None,
    min_label_agreement: float | None = None,
) -> dict[str, Any]:
    """onnxruntime vs PyTorch eager on :func:`verification_images` of ``size``; tolerances
    default to :data:`MAX_LOGIT_DIFF` / :data:`MIN_LABEL_AGREEMENT`."""
    max_diff = MAX_LOGIT_DIFF if max_logit_diff is None else float(max_logit_diff)
    min_agree = MIN_LABEL_AGREEMENT if min_label_agreement is None else float(min_label_agreement)
    images = verification_images(size, batch)
    with torch.no_grad():
        logits_pt, labels_pt = wrapper(torch.from_numpy(images))
    session = make_session(path)
    logits_ort, labels_ort = session.run([OUTPUT_LOGITS, OUTPUT_LABELS], {INPUT_NAME: images})
    expected = (batch, logits_pt.shape[1], *size)
    shapes_ok = (
        logits_ort.shape == expected
        and labels_ort.shape == (batch, *size)
        and logits_ort.dtype == np.float32
        and labels_ort.dtype == np.uint8
    )
    diff = float(np.abs(logits_ort - logits_pt.numpy()).max()) if shapes_ok else float("inf")
    agreement = float((labels_ort == labels_pt.numpy()).mean()) if shapes_ok else 0.0
    return {
        "verify_size": list(size),
        "batch": batch,
        "output_shapes_ok": shapes_ok,
        "logits_shape": list(logits_ort.shape),
        "labels_shape": list(labels_ort.shape),
        "max_abs_logit_diff": diff,
        "max_abs_logit": float(np.abs(logits_pt.numpy()).max()),
        "label_agreement": agreement,
        "classes_present": sorted(int(c) for c in np.unique(labels_pt.numpy())),
        "max_logit_diff_allowed": max_diff,
        "min_label_agreement": min_agree,
        "ok": bool(shapes_ok and diff <= max_diff and agreement >= min_agree),
    }


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
) -> ExportResult:
    """Export ``segmenter`` (``forward`` -> ``.aux`` / ``.main`` logits) to ``out``, verified.

    Raises :class:`ExportVerificationError` (after writing ``<name>.verify.failed.json``) when
    ``onnx.checker`` or the comparison with PyTorch fails; ``out`` and its ``.verify.json``
    are then untouched.
    """
    out = Path(out)
    trace_size, verify_size = tuple(trace_size), tuple(verify_size)
    if trace_size == verify_size:
        raise UssSlamError(f"verify_size must differ from trace_size ({trace_size})")
    if out.suffix != ".onnx":
        raise UssSlamError(f"out must end in .onnx, got {out}")
    wrapper = SegmenterExport(segmenter, metadata.head, metadata.mean, metadata.std).eval()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    started = time.perf_counter()
    try:
        example = torch.from_numpy(verification_images(trace_size, batch=1, seed=1))
        with warnings.catch_warnings(), torch.no_grad():
            # The TorchScript exporter: the torch.export one needs onnxscript (not installed).
            warnings.simplefilter("ignore", DeprecationWarning)
            torch.onnx.export(
                wrapper,
                (example,),
                str(tmp),
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
        model = onnx.load(str(tmp))
        onnx.helper.set_model_props(model, metadata.to_props())
        model.doc_string = (
            f"uss-slam segmenter ({metadata.experiment}, head {metadata.head}): uint8 NHWC RGB "
            "image -> logits (N,C,H,W), labels (N,H,W) uint8; see exports/README.md"
        )
        model.producer_name = "uss-export"
        onnx.save(model, str(tmp))
        export_seconds = time.perf_counter() - started
        report: dict[str, Any] = {
            "model": out.name,
            "head": metadata.head,
            "experiment": metadata.experiment,
            "checkpoint_sha256": metadata.checkpoint_sha256,
            "opset": opset,
            "trace_size": list(trace_size),
            "export_seconds": round(export_seconds, 3),
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
            failed = sidecar(out, ".verify.failed.json")
            _write_json(failed, report)
            raise ExportVerificationError(
                f"{out}: exported model failed verification (checker {report['checker']}, "
                f"max |logit diff| {report.get('max_abs_logit_diff')} <= "
                f"{report.get('max_logit_diff_allowed')}?, label agreement "
                f"{report.get('label_agreement')} >= {report.get('min_label_agreement')}?, "
                f"largest |logit| {report.get('max_abs_logit')}); "
                f"details in {failed}; earlier files left as they were"
            )
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    verify_path = sidecar(out, ".verify.json")
    _write_json(verify_path, report)
    sidecar(out, ".verify.failed.json").unlink(missing_ok=True)
    log.info(
        "wrote %s (max |logit diff| %.2e, label agreement %.5f at %s)",
        out,
        report["max_abs_logit_diff"],
        report["label_agreement"],
        verify_size,
    )
    return ExportResult(path=out, verify_path=verify_path, verify=report, metadata=metadata)


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
) -> ExportResult:
    """Export the segmenter of a ``uss-train`` checkpoint to ``out`` (see :func:`load_checkpoint`
    and :func:`export_segmenter`); ``experiment`` defaults to the training run's ``run_name``."""
    if head not in HEADS:
        raise UssSlamError(f"head must be one of {HEADS}, got {head!r}")
    loaded = load_checkpoint(ckpt_path, net_cfg)
    unknown = [c for c in dynamic_classes if c not in loaded.class_names]
    if unknown:
        raise UssSlamError(f"dynamic_classes {unknown} are not among {loaded.class_names}")
    metadata = SegmenterMetadata(
        class_names=loaded.class_names,
        dynamic_classes=tuple(dynamic_classes),
        mean=IMAGENET_MEAN,
        std=IMAGENET_STD,
        head=head,
        experiment=experiment or loaded.experiment,
        checkpoint_sha256=loaded.sha256,
        version=project_version(),
    )
    result = export_segmenter(
        loaded.segmenter,
        out,
        metadata,
        opset=opset,
        trace_size=trace_size,
        verify_size=verify_size,
        max_logit_diff=max_logit_diff,
        min_label_agreement=min_label_agreement,
    )
    return result


# ---------------------------------------------------------------------------- INT8

KEY_QUANTIZATION = "uss_slam.quantization"
"""Extra ``metadata_props`` key of INT8 models (readers keep it in ``SegmenterMetadata.extra``)."""


def read_calibration_frames(
    root: str | Path, frames: int = 16
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``2 × frames`` RGB frames spread evenly over a TUM folder's ``rgb.txt``, alternately
    assigned to calibration and evaluation (so agreement is measured on frames the calibration
    never saw). Returns ``(calibration, evaluation)`` lists of ``(H, W, 3)`` uint8 RGB."""
    import cv2

    from uss_slam.core.tum_io import read_file_list

    root = Path(root)
    rgb_list = root / "rgb.txt"
    if not rgb_list.is_file():
        raise DataFormatError(rgb_list, "calibration.root must be a TUM RGB-D folder with rgb.txt")
    listing = read_file_list(rgb_list)
    if len(listing) < 2:
        raise DataFormatError(rgb_list, f"needs at least 2 frames, lists {len(listing)}")
    count = min(2 * frames, len(listing))
    picked = np.unique(np.linspace(0, len(listing) - 1, count).round().astype(int))
    images: list[np.ndarray] = []
    for index in picked:
        path = listing.resolve(int(index))
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DataFormatError(path, "not a readable image (listed in rgb.txt)")
        images.append(np.ascontiguousarray(bgr[:, :, ::-1]))
    return images[0::2], images[1::2]


def _median_ms(session: ort.InferenceSession, image: np.ndarray, repeats: int) -> float:
    feed = {INPUT_NAME: image[None]}
    session.run([OUTPUT_LABELS], feed)  # warm-up
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        session.run([OUTPUT_LABELS], feed)
        times.append(time.perf_counter() - started)
    return float(np.median(times) * 1000)


def quantize_int8(
    fp32_path: Path,
    out: Path,
    calibration: Sequence[np.ndarray],
    evaluation: Sequence[np.ndarray],
    *,
    threads: int | None = None,
    repeats: int = 5,
) -> dict[str, Any]:
    """Static INT8 quantisation (onnxruntime, QDQ, per-channel weights, MinMax calibration on
    ``calibration`` frames) of the convolutions of ``fp32_path`` -> ``out`` (atomic).

    Normalisation, resize and argmax stay float. Returns label agreement with the FP32 model on
    ``evaluation`` frames and the median per-frame latency of both (same process, same threads).
    """
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if not calibration or not evaluation:
        raise UssSlamError("INT8 quantisation needs calibration and evaluation frames")

    class Frames(CalibrationDataReader):
        def __init__(self) -> None:
            self.frames = iter(calibration)

        def get_next(self) -> dict[str, np.ndarray] | None:
            frame = next(self.frames, None)
            return None if frame is None else {INPUT_NAME: frame[None]}

    stem = f".{out.name}.{os.getpid()}"
    pre, tmp = out.with_name(stem + ".pre.tmp"), out.with_name(stem + ".tmp")
    root_logger = logging.getLogger()
    level = root_logger.level
    root_logger.setLevel(logging.WARNING)  # the quantiser logs every tensor at INFO on the root
    try:
        quant_pre_process(str(fp32_path), str(pre), skip_symbolic_shape=True)
        quantize_static(
            str(pre),
            str(tmp),
            Frames(),
            quant_format=QuantFormat.QDQ,
            op_types_to_quantize=["Conv"],
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
        )
        root_logger.setLevel(level)
        model = onnx.load(str(tmp))
        props = {p.key: p.value for p in onnx.load(str(fp32_path)).metadata_props}
        props[KEY_QUANTIZATION] = "int8-static-qdq"
        del model.metadata_props[:]
        onnx.helper.set_model_props(model, props)
        onnx.save(model, str(tmp))
        fp32 = make_session(fp32_path, threads)
        int8 = make_session(tmp, threads)
        agree = []
        for frame in evaluation:
            (a,) = fp32.run([OUTPUT_LABELS], {INPUT_NAME: frame[None]})
            (b,) = int8.run([OUTPUT_LABELS], {INPUT_NAME: frame[None]})
            agree.append(float((a == b).mean()))
        fp32_ms = _median_ms(fp32, evaluation[0], repeats)
        int8_ms = _median_ms(int8, evaluation[0], repeats)
        os.replace(tmp, out)
    finally:
        root_logger.setLevel(level)
        pre.unlink(missing_ok=True)
        tmp.unlink(missing_ok=True)
    return {
        "model": out.name,
        "calibration_frames": len(calibration),
        "evaluation_frames": len(evaluation),
        "frame_size": list(evaluation[0].shape[:2]),
        "label_agreement_vs_fp32": float(np.mean(agree)),
        "label_agreement_vs_fp32_min": float(np.min(agree)),
        "threads": threads,
        "fp32_ms": round(fp32_ms, 2),
        "int8_ms": round(int8_ms, 2),
        "speedup": round(fp32_ms / int8_ms, 3),
        "repeats": repeats,
    }


def add_int8(
    result: ExportResult,
    calibration_root: str | Path,
    *,
    frames: int = 16,
    threads: int | None = None,
) -> ExportResult:
    """Build ``<name>.int8.onnx`` next to a verified export; its figures go into
    ``<name>.verify.json`` under ``int8``."""
    calibration, evaluation = read_calibration_frames(calibration_root, frames)
    out = sidecar(result.path, ".int8.onnx")
    figures = quantize_int8(result.path, out, calibration, evaluation, threads=threads)
    figures["calibration_root"] = str(calibration_root)
    verify = {**result.verify, "int8": figures}
    _write_json(result.verify_path, verify)
    log.info(
        "wrote %s: %.2fx faster than FP32 (%.1f vs %.1f ms), label agreement %.4f",
        out,
        figures["speedup"],
        figures["int8_ms"],
        figures["fp32_ms"],
        figures["label_agreement_vs_fp32"],
    )
    return replace(result, verify=verify, int8_path=out)


# ---------------------------------------------------------------------------- CLI


def run(cfg: DictConfig) -> ExportResult:
    """``uss-export`` without Hydra's wrapper (tests call it with a composed config)."""
    if cfg.get("num_threads"):
        torch.set_num_threads(int(cfg.num_threads))
    if cfg.get("ckpt_path") is None:
        raise UssSlamError("ckpt_path=PATH is required (a uss-train .ckpt)")
    ckpt_path = Path(str(cfg.ckpt_path))
    loaded_name = cfg.get("name")
    if loaded_name is None:
        run_cfg_path = run_config_path(ckpt_path)
        run_name = OmegaConf.load(run_cfg_path).get("run_name") if run_cfg_path.is_file() else None
        loaded_name = str(run_name) if run_name else ckpt_path.stem
        if cfg.head != "main":
            loaded_name = f"{loaded_name}_{cfg.head}"
    out = Path(str(cfg.out)) if cfg.get("out") else Path(str(cfg.out_dir)) / f"{loaded_name}.onnx"
    result = export_checkpoint(
        ckpt_path,
        out,
        head=str(cfg.head),
        opset=int(cfg.opset),
        net_cfg=cfg.get("net_config"),
        experiment=cfg.get("experiment"),
        dynamic_classes=list(cfg.dynamic_classes),
        trace_size=tuple(cfg.trace_size),
        verify_size=tuple(cfg.verify_size),
        max_logit_diff=cfg.get("max_logit_diff"),
        min_label_agreement=cfg.get("min_label_agreement"),
    )
    if cfg.get("int8"):
        calibration = cfg.get("calibration") or {}
        if not calibration.get("root"):
            raise UssSlamError(
                "int8=true needs calibration.root=<TUM RGB-D folder of target frames>"
            )
        result = add_int8(
            result,
            str(calibration.root),
            frames=int(calibration.get("frames", 16)),
            threads=cfg.get("num_threads"),
        )
    return result


@hydra.main(version_base="1.3", config_path="../configs", config_name="export")
def main(cfg: DictConfig) -> None:
    with exit_on_user_error("uss-export", (OmegaConfBaseException,)):
        result = run(cfg)
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


if __name__ == "__main__":
    main()

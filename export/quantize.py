"""Static INT8 quantisation of an exported segmenter, calibrated on target-domain frames.

onnxruntime's static quantiser (QDQ format, per-channel int8 weights, uint8 activations, MinMax
calibration) quantises the convolutions only; normalisation, resize and argmax stay float. The
INT8 model keeps the FP32 model's metadata plus :data:`KEY_QUANTIZATION`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort

from uss_slam.core.cli import warning
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import StagedFiles
from uss_slam.core.images import read_colour
from uss_slam.core.onnx_contract import INPUT_NAME, OUTPUT_LABELS
from uss_slam.core.tum_io import read_file_list
from uss_slam.export.outputs import INT8_SUFFIX, ExportResult, sidecar
from uss_slam.export.verify import make_session

log = logging.getLogger(__name__)

KEY_QUANTIZATION = "uss_slam.quantization"
"""Extra ``metadata_props`` key of INT8 models (readers keep it in ``SegmenterMetadata.extra``)."""
DEFAULT_CALIBRATION_FRAMES = 16


def read_calibration_frames(
    root: str | Path, frames: int = DEFAULT_CALIBRATION_FRAMES
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``2 × frames`` RGB frames spread evenly over a TUM folder's ``rgb.txt``, alternately
    assigned to calibration and evaluation (so agreement is measured on frames the calibration
    never saw). Returns ``(calibration, evaluation)`` lists of ``(H, W, 3)`` uint8 RGB.

    A folder with fewer than ``2 × frames`` frames gives all of them, with one warning naming
    both numbers.

    Raises :class:`DataFormatError` naming the folder, ``rgb.txt`` or the image when the folder
    is missing, lists fewer than 2 frames or an image cannot be read.
    """
    root = Path(root)
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise UssSlamError(f"calibration.frames must be a positive integer, got {frames!r}")
    if not root.is_dir():
        raise DataFormatError(
            root, "calibration.root is not a folder (expected a TUM RGB-D folder with rgb.txt)"
        )
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
        bgr = read_colour(path)
        images.append(np.ascontiguousarray(bgr[:, :, ::-1]))
    if count < 2 * frames:  # after the reads: a bad folder is one error line, no warning
        warning(
            f"calibration.frames={frames} asks for {frames} calibration and {frames} evaluation "
            f"frames, but {rgb_list} lists {len(listing)}: {(count + 1) // 2} calibrate and "
            f"{count // 2} evaluate"
        )
    return images[0::2], images[1::2]


@dataclass(frozen=True)
class CalibrationSet:
    """Frames of one target folder, read before an export starts (a bad folder fails first)."""

    root: Path
    calibration: list[np.ndarray]
    """Frames the quantiser calibrates on, ``(H, W, 3)`` uint8 RGB."""
    evaluation: list[np.ndarray]
    """Other frames of the same folder, on which INT8 labels are compared with FP32."""

    @classmethod
    def read(cls, root: str | Path, frames: int = DEFAULT_CALIBRATION_FRAMES) -> CalibrationSet:
        calibration, evaluation = read_calibration_frames(root, frames)
        return cls(Path(root), calibration, evaluation)


def _median_ms(session: ort.InferenceSession, image: np.ndarray, repeats: int) -> float:
    feed = {INPUT_NAME: image[None]}
    session.run([OUTPUT_LABELS], feed)  # warm-up
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        session.run([OUTPUT_LABELS], feed)
        times.append(time.perf_counter() - started)
    return float(np.median(times) * 1000)


def write_int8(
    fp32_path: Path,
    dest: Path,
    calibration: Sequence[np.ndarray],
    evaluation: Sequence[np.ndarray],
    *,
    threads: int | None = None,
    repeats: int = 5,
) -> dict[str, Any]:
    """Quantise ``fp32_path`` into ``dest`` (written in place: callers stage it) and measure it.

    Returns label agreement with the FP32 model on ``evaluation`` frames and the median
    per-frame latency of both (same process, same threads).
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

    with StagedFiles() as scratch:
        pre = scratch.path(dest.with_name(dest.name + ".pre"))
        root_logger = logging.getLogger()
        level = root_logger.level
        root_logger.setLevel(logging.WARNING)  # the quantiser logs every tensor at INFO on the root
        try:
            quant_pre_process(str(fp32_path), str(pre), skip_symbolic_shape=True)
            quantize_static(
                str(pre),
                str(dest),
                Frames(),
                quant_format=QuantFormat.QDQ,
                op_types_to_quantize=["Conv"],
                per_channel=True,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
            )
        finally:
            root_logger.setLevel(level)
    model = onnx.load(str(dest))
    props = {p.key: p.value for p in onnx.load(str(fp32_path)).metadata_props}
    props[KEY_QUANTIZATION] = "int8-static-qdq"
    del model.metadata_props[:]
    onnx.helper.set_model_props(model, props)
    onnx.save(model, str(dest))
    fp32 = make_session(fp32_path, threads)
    int8 = make_session(dest, threads)
    agree = []
    for frame in evaluation:
        (a,) = fp32.run([OUTPUT_LABELS], {INPUT_NAME: frame[None]})
        (b,) = int8.run([OUTPUT_LABELS], {INPUT_NAME: frame[None]})
        agree.append(float((a == b).mean()))
    fp32_ms = _median_ms(fp32, evaluation[0], repeats)
    int8_ms = _median_ms(int8, evaluation[0], repeats)
    return {
        "model": dest.name,
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


def quantize_int8(
    fp32_path: Path,
    out: Path,
    calibration: Sequence[np.ndarray],
    evaluation: Sequence[np.ndarray],
    *,
    threads: int | None = None,
    repeats: int = 5,
) -> dict[str, Any]:
    """Static INT8 quantisation of ``fp32_path`` -> ``out`` (atomic), calibrated on
    ``calibration`` frames; figures as :func:`write_int8`."""
    out = Path(out)
    with StagedFiles() as staged:
        tmp = staged.path(out)
        figures = write_int8(
            Path(fp32_path), tmp, calibration, evaluation, threads=threads, repeats=repeats
        )
        staged.commit()
    return {**figures, "model": out.name}


def log_int8(path: Path, figures: dict[str, Any]) -> None:
    log.info(
        "wrote %s: %.2fx faster than FP32 (%.1f vs %.1f ms), label agreement %.4f",
        path,
        figures["speedup"],
        figures["int8_ms"],
        figures["fp32_ms"],
        figures["label_agreement_vs_fp32"],
    )


def add_int8(
    result: ExportResult,
    calibration_root: str | Path,
    *,
    frames: int = DEFAULT_CALIBRATION_FRAMES,
    threads: int | None = None,
) -> ExportResult:
    """Build ``<name>.int8.onnx`` next to an existing verified export; its figures go into
    ``<name>.verify.json`` under ``int8`` (both files replaced together)."""
    frames_set = CalibrationSet.read(calibration_root, frames)
    out = sidecar(result.path, INT8_SUFFIX)
    with StagedFiles() as staged:
        tmp = staged.path(out)
        figures = write_int8(
            result.path, tmp, frames_set.calibration, frames_set.evaluation, threads=threads
        )
        figures["model"] = out.name
        figures["calibration_root"] = str(calibration_root)
        verify = {**result.verify, "int8": figures}
        staged.write_json(result.verify_path, verify)
        staged.commit()
    log_int8(out, figures)
    return replace(result, verify=verify, int8_path=out)

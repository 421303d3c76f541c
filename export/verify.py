"""Verification of an exported model: onnxruntime against PyTorch eager on test images."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import torch
import torch.nn.functional as F

from uss_slam.core.errors import UssSlamError
from uss_slam.core.onnx_contract import INPUT_NAME, OUTPUT_LABELS, OUTPUT_LOGITS
from uss_slam.export.wrapper import SegmenterExport

MAX_LOGIT_DIFF = 1e-4
"""Largest accepted |onnxruntime - PyTorch| logit difference in verification, for logits up to
:data:`MAX_LOGIT_DIFF` / :data:`MAX_RELATIVE_LOGIT_DIFF` = 10 in size."""
MAX_RELATIVE_LOGIT_DIFF = 1e-5
"""Beyond that the default tolerance grows with the largest |logit| (float32 summation errors
scale with the values summed): allowed = max(MAX_LOGIT_DIFF, MAX_RELATIVE_LOGIT_DIFF * max|logit|).
A model trained from scratch can reach logits of 50-100, where ~2e-4 differences are float32
reordering, not an export fault."""
MIN_LABEL_AGREEMENT = 0.999
"""Smallest accepted fraction of equal labels (onnxruntime vs PyTorch) in verification."""
DEFAULT_VERIFY_SIZE = (120, 160)
"""(H, W) of the verification batch; must differ from the trace size."""
VERIFY_BATCH = 2


class ExportVerificationError(UssSlamError):
    """The exported model does not reproduce PyTorch (or fails ``onnx.checker``)."""


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
    """A CPU onnxruntime session; ``threads`` intra-op threads (None: onnxruntime's default)."""
    options = ort.SessionOptions()
    if threads:
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def verify_model(
    path: Path,
    wrapper: SegmenterExport,
    size: tuple[int, int],
    batch: int = VERIFY_BATCH,
    max_logit_diff: float | None = None,
    min_label_agreement: float | None = None,
) -> dict[str, Any]:
    """onnxruntime vs PyTorch eager on :func:`verification_images` of ``size``. Tolerances:
    ``max_logit_diff`` is absolute; ``None`` = max(:data:`MAX_LOGIT_DIFF`,
    :data:`MAX_RELATIVE_LOGIT_DIFF` × the largest |logit|); ``min_label_agreement`` ``None`` =
    :data:`MIN_LABEL_AGREEMENT`."""
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
    largest = float(np.abs(logits_pt.numpy()).max())
    if max_logit_diff is not None:
        max_diff = float(max_logit_diff)
    else:
        max_diff = max(MAX_LOGIT_DIFF, MAX_RELATIVE_LOGIT_DIFF * largest)
    diff = float(np.abs(logits_ort - logits_pt.numpy()).max()) if shapes_ok else float("inf")
    agreement = float((labels_ort == labels_pt.numpy()).mean()) if shapes_ok else 0.0
    return {
        "verify_size": list(size),
        "batch": batch,
        "output_shapes_ok": shapes_ok,
        "logits_shape": list(logits_ort.shape),
        "labels_shape": list(labels_ort.shape),
        "max_abs_logit_diff": diff,
        "max_abs_logit": largest,
        "label_agreement": agreement,
        "classes_present": sorted(int(c) for c in np.unique(labels_pt.numpy())),
        "max_logit_diff_allowed": max_diff,
        "min_label_agreement": min_agree,
        "ok": bool(shapes_ok and diff <= max_diff and agreement >= min_agree),
    }


def failure_message(out: Path, report: dict[str, Any], failed: Path) -> str:
    """The one line :class:`ExportVerificationError` says about a failed ``report``."""
    checker = (str(report["checker"]).strip().splitlines() or [""])[0]
    return (
        f"{out}: exported model failed verification (checker {checker}, "
        f"max |logit diff| {report.get('max_abs_logit_diff')} <= "
        f"{report.get('max_logit_diff_allowed')}?, label agreement "
        f"{report.get('label_agreement')} >= {report.get('min_label_agreement')}?, "
        f"largest |logit| {report.get('max_abs_logit')}); "
        f"details in {failed}; earlier files left as they were"
    )

"""The segmentation metrics against hand-computed answers."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.core.seg_metrics import (
    RATE_NAMES,
    BinaryCounts,
    confusion_matrix,
    frame_outcome,
    iou_per_class,
    iou_report,
    mask_counts,
    mask_metrics,
    mean_iou,
)

# 3 x 4 label maps; (1, 1) is ignored in the truth.
TRUTH = np.array([[0, 0, 1, 1], [0, 255, 1, 2], [3, 3, 2, 2]], np.uint8)
PRED = np.array([[0, 1, 1, 1], [0, 0, 0, 2], [3, 0, 2, 1]], np.uint8)
# rows truth, columns prediction, counted by hand over the 11 valid pixels
MATRIX = np.array([[2, 1, 0, 0], [1, 2, 0, 0], [0, 1, 2, 0], [1, 0, 0, 1]])


def test_confusion_matrix_by_hand() -> None:
    matrix = confusion_matrix(TRUTH, PRED, 4)
    assert matrix.dtype == np.int64
    np.testing.assert_array_equal(matrix, MATRIX)
    # the ignored pixel counts nowhere, whatever was predicted there
    other = PRED.copy()
    other[1, 1] = 3
    np.testing.assert_array_equal(confusion_matrix(TRUTH, other, 4), MATRIX)


def test_iou_and_miou_by_hand() -> None:
    # TP / (column sum + row sum - TP): 2 / (4 + 3 - 2), 2 / (4 + 3 - 2), 2 / (2 + 3 - 2), 1 / 2
    iou = iou_per_class(MATRIX)
    np.testing.assert_allclose(iou, [2 / 5, 2 / 5, 2 / 3, 1 / 2], rtol=0, atol=1e-15)
    assert mean_iou(iou) == pytest.approx(59 / 120, abs=1e-15)


def test_class_absent_from_truth_and_prediction_is_excluded() -> None:
    matrix = confusion_matrix(TRUTH, PRED, 5)  # class 4 is in neither
    iou = iou_per_class(matrix)
    assert math.isnan(iou[4])
    assert mean_iou(iou) == pytest.approx(59 / 120, abs=1e-15)
    report = iou_report(matrix, ["a", "b", "c", "d", "e"])
    assert report["IoU"]["e"] is None and report["IoU"]["c"] == pytest.approx(2 / 3)
    assert report["mIoU"] == pytest.approx(59 / 120)
    # a class predicted but absent from the truth has IoU 0 and counts in the mean
    only_pred = np.zeros((2, 2), np.int64)
    only_pred[0, 1] = 3
    only_pred[0, 0] = 1
    np.testing.assert_array_equal(iou_per_class(only_pred), [0.25, 0.0])
    assert mean_iou(iou_per_class(only_pred)) == 0.125


def test_nothing_defined_gives_nan_and_none() -> None:
    matrix = np.zeros((3, 3), np.int64)
    assert np.isnan(iou_per_class(matrix)).all() and math.isnan(mean_iou(iou_per_class(matrix)))
    assert iou_report(matrix, ["a", "b", "c"]) == {"mIoU": None, "IoU": dict.fromkeys("abc")}


def test_bad_inputs_are_errors() -> None:
    with pytest.raises(UssSlamError, match=r"prediction shape \(2, 2\) differs"):
        confusion_matrix(TRUTH, PRED[:2, :2], 4)
    with pytest.raises(UssSlamError, match=r"truth holds class id 3; expected 0..2 or 255"):
        confusion_matrix(TRUTH, np.minimum(PRED, 2), 3)
    truth = np.minimum(TRUTH, 2)
    truth[1, 1] = 255
    with pytest.raises(UssSlamError, match=r"prediction holds class id 3; expected 0..2$"):
        confusion_matrix(truth, PRED, 3)
    with pytest.raises(UssSlamError, match="2 class names for a 4-class matrix"):
        iou_report(MATRIX, ["a", "b"])


def test_person_mask_pixel_counts_by_hand() -> None:
    counts = mask_counts(TRUTH, PRED, [1])
    # truth person: (0,2) (0,3) (1,2); prediction: (0,1) (0,2) (0,3) (2,3)
    assert counts == BinaryCounts(tp=2, fp=2, tn=6, fn=1) and counts.total == 11
    assert counts.iou == pytest.approx(2 / 5)
    rates = counts.rates()
    assert list(rates) == list(RATE_NAMES)
    assert rates == pytest.approx(
        {"FPR": 2 / 8, "FNR": 1 / 3, "recall": 2 / 3, "precision": 2 / 4, "PWC": 3 / 11}
    )
    # several dynamic classes: one mask of person or chair; truth (0,2) (0,3) (1,2) (1,3) (2,2)
    # (2,3), prediction (0,1) (0,2) (0,3) (1,3) (2,2) (2,3)
    assert mask_counts(TRUTH, PRED, [1, 2]) == BinaryCounts(tp=5, fp=1, tn=4, fn=1)


def test_frame_outcome_follows_the_papers_definitions() -> None:
    person = mask_counts(TRUTH, PRED, [1])  # IoU 0.4
    assert frame_outcome(person, iou_threshold=0.5) == BinaryCounts(fn=1)  # not correctly
    assert frame_outcome(person, iou_threshold=0.4) == BinaryCounts(tp=1)
    assert frame_outcome(BinaryCounts(fp=3, tn=9)) == BinaryCounts(fp=1)  # none there, some seen
    assert frame_outcome(BinaryCounts(tn=12)) == BinaryCounts(tn=1)
    assert frame_outcome(BinaryCounts(fn=4, tn=8)) == BinaryCounts(fn=1)  # missed entirely
    # min_pixels: a 2-pixel false detection is not "an object segmented" at min_pixels=3
    assert frame_outcome(BinaryCounts(fp=2, tn=10), min_pixels=3) == BinaryCounts(tn=1)
    with pytest.raises(UssSlamError, match="iou_threshold"):
        frame_outcome(person, iou_threshold=0.0)
    with pytest.raises(UssSlamError, match="min_pixels"):
        frame_outcome(person, min_pixels=0)


def test_mask_metrics_frames_pooled_and_mean() -> None:
    frames = [
        BinaryCounts(tp=8, fp=1, tn=90, fn=1),  # TP frame (IoU 0.8)
        BinaryCounts(tp=2, fp=2, tn=95, fn=1),  # FN frame (IoU 0.4)
        BinaryCounts(tp=0, fp=5, tn=95, fn=0),  # FP frame
        BinaryCounts(tp=0, fp=0, tn=100, fn=0),  # TN frame
        BinaryCounts(tp=0, fp=0, tn=96, fn=4),  # FN frame (missed)
    ]
    result = mask_metrics(frames)
    assert result["frame_count"] == 5
    table = result["frames"]
    assert table["counts"] == {"TP": 1, "FP": 1, "TN": 1, "FN": 2}
    assert (table["iou_threshold"], table["min_pixels"]) == (0.5, 1)
    expected = {"FPR": 1 / 2, "FNR": 2 / 3, "recall": 1 / 3, "precision": 1 / 2, "PWC": 3 / 5}
    assert {k: table[k] for k in RATE_NAMES} == pytest.approx(expected)
    pooled = result["pixels_pooled"]
    assert pooled["counts"] == {"TP": 10, "FP": 8, "TN": 476, "FN": 6}
    assert pooled["recall"] == pytest.approx(10 / 16) and pooled["PWC"] == pytest.approx(14 / 500)
    mean = result["pixels_mean"]
    # recall is defined in the 3 frames with people: 8/9, 2/3, 0
    assert mean["recall"] == pytest.approx((8 / 9 + 2 / 3 + 0) / 3)
    # precision in the 3 frames with a prediction: 8/9, 1/2, 0
    assert mean["precision"] == pytest.approx((8 / 9 + 1 / 2 + 0) / 3)
    assert mean["FPR"] == pytest.approx((1 / 91 + 2 / 97 + 5 / 100 + 0 + 0) / 5)
    assert mean["PWC"] == pytest.approx((2 + 3 + 5 + 0 + 4) / 500)


def test_empty_sequence_gives_undefined_rates() -> None:
    result = mask_metrics([])
    assert result["frame_count"] == 0
    assert all(result["frames"][k] is None for k in RATE_NAMES)
    assert all(v is None for v in result["pixels_mean"].values())


def test_module_does_not_import_torch() -> None:
    code = "import sys, uss_slam.core.seg_metrics; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

"""studies/orbslam3_partial_masks.py: the frames it counts on are the ones ``uss-slam`` feeds
ORB-SLAM3, and ground-truth masks leave no keypoint on the walkers."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.slam_eval.filters.semantic import SemanticFilter
from uss_slam.slam_eval.sequence import TumSequence
from uss_slam.slam_eval.systems.orbslam3.masking import blank_dynamic, fill_dynamic
from uss_slam.slam_eval.systems.orbslam3.vocabulary import ORB_SETTINGS
from uss_slam.testing.scripts import load_script

orbslam3_partial_masks = load_script(
    Path(__file__).resolve().parents[2] / "studies" / "orbslam3_partial_masks.py"
)
FILLS, filled, main, measure, model_masks = (
    orbslam3_partial_masks.FILLS,
    orbslam3_partial_masks.filled,
    orbslam3_partial_masks.main,
    orbslam3_partial_masks.measure,
    orbslam3_partial_masks.model_masks,
)


def test_the_filled_frames_are_uss_slams(synthetic_sequence) -> None:
    seq = TumSequence(synthetic_sequence(preset="walking_xyz", frames=3, size=(160, 120)),
                      load_labels=True)  # fmt: skip
    semantic = SemanticFilter(["person"], 5)
    masks = model_masks(seq, "labels", semantic)
    frame = next(f for f in seq.frames() if masks[f.index].any())
    mask = masks[frame.index]
    gray, depth = filled(frame, mask, "unblanked")
    assert gray is frame.gray and depth is frame.depth
    rgb, grey_depth = blank_dynamic(frame.rgb, frame.depth, mask, 128)
    gray, depth = filled(frame, mask, "grey")
    assert np.array_equal(gray, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    assert np.array_equal(depth, grey_depth) and np.all(depth[mask] == 0)
    gray, _ = filled(frame, mask, "inpaint")
    expected = cv2.cvtColor(fill_dynamic(frame.rgb, mask, "inpaint"), cv2.COLOR_RGB2GRAY)
    assert np.array_equal(gray, expected)
    gray, _ = filled(frame, mask, "smooth")
    assert np.array_equal(gray[~mask], frame.gray[~mask])  # only the mask is filled
    with pytest.raises(ValueError, match="fill: one of unblanked, grey"):
        filled(frame, mask, "black")

    orb = cv2.ORB_create(**ORB_SETTINGS)
    result = measure(seq, masks, orb)
    assert result["recall"] == 1.0
    assert result["unblanked"]["walker"] > 0
    for how in FILLS[1:]:  # the dilated ground truth covers every walker pixel
        assert result[how]["walker"] == 0 and result[how]["share"] == 0


def test_a_missing_model_is_one_error(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit):
        main(["--sequence", str(tmp_path), "--model", str(tmp_path / "m.onnx")])
    assert f"--model {tmp_path / 'm.onnx'}: no such file (an ONNX export, or 'labels')" in (
        capsys.readouterr().err
    )

"""studies/sensor_parts.py: each part switches off what it names and nothing else."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uss_slam.synthetic.sequence import SequenceRenderer
from uss_slam.synthetic.styles import depth_to_png
from uss_slam.testing.scripts import load_script

sensor_parts = load_script(Path(__file__).resolve().parents[2] / "studies" / "sensor_parts.py")
PARTS, style_without = sensor_parts.PARTS, sensor_parts.style_without


def _frame(part: str):
    with style_without(part):
        # a turning hand-held camera (blur to remove) with a global shutter: its depth is the
        # render's, unwarped
        renderer = SequenceRenderer("handheld_rpy", 60, (160, 120), 3, "target", "office", "global")
        return renderer.frame(40)


def test_each_part_changes_only_its_own_image() -> None:
    full = _frame("full")
    assert np.array_equal(_frame("full").rgb, full.rgb)  # rendering is deterministic
    for part in ("no_blur", "no_image_noise"):
        f = _frame(part)
        assert not np.array_equal(f.rgb, full.rgb), part
        assert np.array_equal(f.depth, full.depth), part
    exact = _frame("exact_depth")
    assert np.array_equal(exact.rgb, full.rgb)
    assert np.array_equal(exact.depth, depth_to_png(exact.clean_depth))
    assert not np.array_equal(exact.depth, full.depth)
    # without noise the colour image is smoother: smaller pixel-to-pixel differences
    quiet = _frame("no_image_noise").rgb.astype(np.int16)
    assert (
        np.abs(np.diff(quiet, axis=1)).mean()
        < np.abs(np.diff(full.rgb.astype(np.int16), axis=1)).mean()
    )


def test_an_unknown_part_is_named() -> None:
    message = f"unknown part 'blur'; choose from {', '.join(PARTS)}"
    with pytest.raises(ValueError, match=message), style_without("blur"):
        pass

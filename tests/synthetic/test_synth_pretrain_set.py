"""The pretraining set's renderer: a VOC tree whose images are lit as the source or the target."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from uss_slam.synthetic.output import SynthArgumentError
from uss_slam.synthetic.voc import image_style, render_voc


def test_mixed_lighting_draws_both_styles_with_even_odds() -> None:
    styles = [image_style(900, i, "mixed") for i in range(400)]
    share = styles.count("target") / len(styles)
    assert set(styles) == {"source", "target"}
    assert 0.4 < share < 0.6
    assert styles == [image_style(900, i, "mixed") for i in range(400)]  # deterministic
    assert {image_style(900, i, "source") for i in range(50)} == {"source"}


def test_mixed_tree_keeps_the_content_and_changes_the_lit_images(tmp_path: Path) -> None:
    kwargs = {"images": 6, "size": (96, 72), "seed": 900, "outfits": "all"}
    plain = render_voc(tmp_path / "plain", **kwargs)
    mixed = render_voc(tmp_path / "mixed", lighting="mixed", **kwargs)
    names = sorted(p.stem for p in (plain / "JPEGImages").iterdir())
    assert names == sorted(p.stem for p in (mixed / "JPEGImages").iterdir())
    for index, name in enumerate(names):
        labels = [
            np.asarray(Image.open(r / "SegmentationClass" / f"{name}.png")) for r in (plain, mixed)
        ]
        np.testing.assert_array_equal(labels[0], labels[1])
        rgb = [np.asarray(Image.open(r / "JPEGImages" / f"{name}.jpg")) for r in (plain, mixed)]
        same = np.array_equal(rgb[0], rgb[1])
        assert same == (image_style(900, index, "mixed") == "source"), name


def test_unknown_lighting_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(
        SynthArgumentError, match="unknown lighting 'dusk'; choose one of source, mixed"
    ):
        render_voc(tmp_path / "x", images=1, size=(64, 48), lighting="dusk")

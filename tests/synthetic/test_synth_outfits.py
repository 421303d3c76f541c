"""The varied wardrobe of the VOC-style set changes the people's clothing and nothing else."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.synthetic.output import SynthArgumentError
from uss_slam.synthetic.textures import ROLE_INDEX, WARDROBE_IMAGES, wardrobe_bank
from uss_slam.synthetic.voc import render_voc_sample

PERSON = CLASS_NAMES.index("person")


def _person_image(outfits: str):
    for index in range(40):
        sample = render_voc_sample(0, index, (160, 120), outfits)
        if (sample.labels == PERSON).mean() > 0.02:
            return index, sample
    raise AssertionError("no image with a person among the first 40")  # pragma: no cover


def test_varied_outfits_change_only_the_people() -> None:
    index, varied = _person_image("varied")
    classic = render_voc_sample(0, index, (160, 120), "classic")
    assert np.array_equal(varied.labels, classic.labels)  # same layout, viewpoint, people
    person = varied.labels == PERSON
    # filtered texture lookups blend across a material edge by a pixel or two
    near_person = cv2.dilate(person.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert np.array_equal(varied.rgb[~near_person], classic.rgb[~near_person])
    differs = np.abs(varied.rgb.astype(int) - classic.rgb.astype(int)).sum(-1) > 30
    assert differs[person].mean() > 0.5  # the clothes (and skin, hair) are other materials


def test_varied_outfits_are_deterministic_and_change_every_wardrobe() -> None:
    index, first = _person_image("varied")
    again = render_voc_sample(0, index, (160, 120), "varied")
    assert np.array_equal(first.rgb, again.rgb)
    a, b = wardrobe_bank(0, 0), wardrobe_bank(0, 1)
    for role in ("shirt_0", "trousers_3"):
        assert not np.array_equal(a.images[ROLE_INDEX[role]], b.images[ROLE_INDEX[role]])
    assert np.array_equal(a.images[ROLE_INDEX["floor"]], b.images[ROLE_INDEX["floor"]])
    assert WARDROBE_IMAGES == 20


def test_unknown_outfits_named() -> None:
    with pytest.raises(
        SynthArgumentError, match="unknown outfits .plain.; choose one of classic, varied, all"
    ):
        render_voc_sample(0, 0, (160, 120), "plain")

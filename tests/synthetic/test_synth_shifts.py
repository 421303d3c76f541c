"""The pieces the synthetic shifts are made of: the ``all`` wardrobe, walkers dressed per
sequence, and the VOC-layout content in the target style."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.synthetic.output import SynthArgumentError
from uss_slam.synthetic.sequence import SequenceRenderer
from uss_slam.synthetic.textures import (
    ALL_ROOM_BANKS,
    ROLE_INDEX,
    ROLES,
    all_wardrobe_bank,
    any_garment,
    texture_bank,
    walker_bank,
)
from uss_slam.synthetic.voc import render_voc_sample

PERSON = CLASS_NAMES.index("person")
SIZE = (160, 120)


def _near(mask: np.ndarray, pixels: int = 5) -> np.ndarray:
    return cv2.dilate(mask.astype(np.uint8), np.ones((pixels, pixels), np.uint8)) > 0


def test_drawn_outfits_change_only_the_people() -> None:
    drawn = SequenceRenderer("walking_xyz", 10, SIZE, seed=3, outfits="drawn").frame(4)
    office = SequenceRenderer("walking_xyz", 10, SIZE, seed=3, outfits="office").frame(4)
    assert np.array_equal(drawn.labels, office.labels)
    assert np.array_equal(drawn.depth, office.depth)
    person = drawn.labels == PERSON
    assert person.mean() > 0.05
    # target frames are blurred (motion, optics): compare away from the people's outlines
    away = ~_near(person, 9)
    assert np.abs(drawn.rgb[away].astype(int) - office.rgb[away].astype(int)).max() <= 2
    differs = np.abs(drawn.rgb.astype(int) - office.rgb.astype(int)).sum(-1) > 30
    assert differs[person].mean() > 0.3


def test_each_sequence_dresses_its_walkers_anew() -> None:
    a, b, c = (walker_bank("target", 1, "walking_xyz"), walker_bank("target", 2, "walking_xyz"),
               walker_bank("target", 1, "walking_rpy"))  # fmt: skip
    for role in ("shirt_0", "trousers_1"):
        i = ROLE_INDEX[role]
        assert not np.array_equal(a.images[i], b.images[i])
        assert not np.array_equal(a.images[i], c.images[i])
    office = texture_bank("target", 0)
    for role in ("floor", "wall_a", "desk"):  # the office itself is the recordings' one
        assert np.array_equal(a.images[ROLE_INDEX[role]], office.images[ROLE_INDEX[role]])


def test_all_wardrobe_draws_every_garment_family() -> None:
    """``any_garment``'s first draw picks the family (source prints, varied fabrics, target
    cloths): over 30 streams all three come up; the rooms come from both material families."""
    from uss_slam.synthetic.seeding import stream

    shirt = ROLES[ROLE_INDEX["shirt_0"]]
    families = set()
    for k in range(30):
        rng = stream(k, "probe")
        family = int(stream(k, "probe").integers(0, 3))
        img = any_garment(shirt, rng)
        assert img.shape == (shirt.size, shirt.size, 3)
        families.add(family)
    assert families == {0, 1, 2}
    rooms = {ALL_ROOM_BANKS[w % len(ALL_ROOM_BANKS)][0] for w in range(6)}
    assert rooms == {"source", "target"}
    assert ("target", 0) not in ALL_ROOM_BANKS  # never the recordings' office
    bank = all_wardrobe_bank(3, 3)
    assert np.array_equal(bank.images[ROLE_INDEX["floor"]],
                          texture_bank("target", 1).images[ROLE_INDEX["floor"]])  # fmt: skip


def test_voc_target_style_keeps_the_content() -> None:
    source = render_voc_sample(0, 2, SIZE, "classic", "source")
    target = render_voc_sample(0, 2, SIZE, "classic", "target")
    assert np.array_equal(source.labels, target.labels)
    assert source.rgb.mean() - target.rgb.mean() > 5  # dimmer light, black level, cast
    again = render_voc_sample(0, 2, SIZE, "classic", "target")
    assert np.array_equal(target.rgb, again.rgb)


def test_unknown_names_are_one_line_errors() -> None:
    with pytest.raises(
        SynthArgumentError, match="unknown outfits 'suits'; choose one of office, drawn"
    ):
        SequenceRenderer("walking_xyz", 10, SIZE, outfits="suits")
    with pytest.raises(
        SynthArgumentError, match="unknown style 'night'; choose one of source, target"
    ):
        render_voc_sample(0, 0, SIZE, "classic", "night")


def test_near_views_face_a_person_and_leave_the_other_images_as_they_were() -> None:
    """``near``: that share of the VOC-layout images faces a person at walking distance; the
    others are the images of ``near=0`` (a separate random stream decides), so sets made
    without near views do not change."""
    from uss_slam.synthetic.voc import render_voc_sample

    plain = [render_voc_sample(0, i, SIZE, "all") for i in range(12)]
    mixed = [render_voc_sample(0, i, SIZE, "all", near=0.5) for i in range(12)]
    same = [np.array_equal(a.labels, b.labels) and np.array_equal(a.rgb, b.rgb)
            for a, b in zip(plain, mixed, strict=True)]  # fmt: skip
    assert 2 <= same.count(False) <= 10  # about half of them are near views
    near = [m for m, s in zip(mixed, same, strict=True) if not s]
    share = np.mean([(m.labels == PERSON).mean() for m in near])
    assert share > 2 * np.mean([(p.labels == PERSON).mean() for p in plain])
    assert all((m.labels == PERSON).mean() > 0.02 for m in near)  # each shows its person
    with pytest.raises(SynthArgumentError, match=r"near must be a share in \[0, 1\], got 1.5"):
        render_voc_sample(0, 0, SIZE, "all", near=1.5)


def test_the_tum_like_source_set_has_near_views() -> None:
    from uss_slam.pipelines.synthetic_data import DemoData

    assert DemoData(shift="tum_like").near == 0.3
    assert DemoData(shift="tum_like").record()["source_near"] == 0.3
    assert "source_near" not in DemoData(shift="appearance").record()
    assert "source_near" not in DemoData(shift="full").record()

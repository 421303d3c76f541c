"""studies/fresh_setups9.py and studies/fresh_cases9.txt: the ninth set's preparations make the
files they say on a made-up world, and every case's template forms (no case is run here)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
STUDIES = ROOT / "studies"


def _world(w: Path) -> dict[str, str]:
    """A made-up world: a sequence of 12 listed frames, a VOC tree of 4 images, an estimate of
    12 poses."""
    import numpy as np
    from PIL import Image

    seq = w / "seq"
    (seq / "rgb").mkdir(parents=True)
    rows = []
    for i in range(12):
        pixels = np.random.default_rng(i).integers(0, 255, (12, 16, 3), dtype=np.uint8)
        Image.fromarray(pixels).save(seq / "rgb" / f"{i}.5.png")
        rows.append(f"{i}.5 rgb/{i}.5.png")
    (seq / "rgb.txt").write_text("# colour images\n" + "\n".join(rows) + "\n")
    (seq / "intrinsics.yaml").write_text("fx: 10.0\nfy: 10.0\ncx: 8.0\ncy: 6.0\n")
    voc = w / "voc" / "VOCdevkit" / "VOC2012"
    for folder in ("JPEGImages", "SegmentationClass", "ImageSets/Segmentation"):
        (voc / folder).mkdir(parents=True)
    for i in range(4):
        pixels = np.random.default_rng(i).integers(0, 255, (12, 16, 3), dtype=np.uint8)
        Image.fromarray(pixels).save(voc / "JPEGImages" / f"2012_{i:06d}.jpg")
        Image.fromarray(np.zeros((12, 16), np.uint8)).save(
            voc / "SegmentationClass" / f"2012_{i:06d}.png"
        )
    names = "".join(f"2012_{i:06d}\n" for i in range(4))
    (voc / "ImageSets" / "Segmentation" / "train.txt").write_text(names)
    est = w / "trajectory.txt"
    est.write_text("".join(f"{i}.5 0 0 {i / 10} 0 0 0 1\n" for i in range(12)))
    return {"W": str(w), "seq": str(seq), "voc": str(voc), "est": str(est)}


def test_the_ninth_sets_setups_make_what_they_say(fresh, tmp_path) -> None:
    from fresh_setups import seqcopy
    from fresh_setups9 import NINTH

    world = _world(tmp_path / "w")
    listed = [r for r in Path(world["seq"], "rgb.txt").read_text().splitlines() if r[0] != "#"]

    c = tmp_path / "extras"
    c.mkdir()
    seqcopy(c, world)
    NINTH["seq_tum_extras"](c, world)
    rows = (c / "seq" / "accelerometer.txt").read_text().splitlines()
    assert rows[0] == "# accelerometer data"
    data = [r for r in rows if not r.startswith("#")]
    assert [r.split()[0] for r in data] == [r.split()[0] for r in listed]
    assert all(len(r.split()) == 4 for r in data)

    c = tmp_path / "orbslam"
    c.mkdir()
    seqcopy(c, world)
    NINTH["intr_orbslam_settings"](c, world)
    text = (c / "seq" / "intrinsics.yaml").read_text()
    assert text.startswith("%YAML:1.0\n") and "Camera.fx: 517.306408" in text
    assert "\nfx:" not in text

    c = tmp_path / "keyframes"
    c.mkdir()
    NINTH["est_keyframes"](c, world)
    kept = (c / "KeyFrameTrajectory.txt").read_text().splitlines()
    assert [r.split()[0] for r in kept] == ["0.5", "5.5", "10.5"]

    c = tmp_path / "voc"
    c.mkdir()
    NINTH["voc_unpacked"](c, world)
    voc = c / "voc"
    assert sorted(p.name for p in (voc / "SegmentationObject").iterdir()) == sorted(
        p.name for p in (voc / "SegmentationClass").iterdir()
    )
    assert len(list((voc / "JPEGImages").iterdir())) == 4 + 3
    assert (voc / "ImageSets" / "Segmentation" / "train.txt").read_text().count("\n") == 4
    assert (voc / "Annotations").is_dir()


@pytest.mark.parametrize(
    ("name", "shipped", "keys"),
    [("primary_slam", "slam_eval", {"sequence", "progress"}),
     ("primary_experiments", "experiments", {"dry_run", "sequences"})],
)  # fmt: skip
def test_the_ninth_sets_own_configs_start_from_a_shipped_one(fresh, tmp_path, name, shipped, keys):
    from fresh_setups9 import NINTH

    world = _world(tmp_path / "w")
    c = tmp_path / "c"
    c.mkdir()
    NINTH[name](c, world)
    config = yaml.safe_load((c / "cfg" / "mine.yaml").read_text())
    assert config["defaults"] == [shipped, "_self_"]
    assert (ROOT / "configs" / f"{shipped}.yaml").is_file()
    assert keys <= set(config)
    if name == "primary_slam":
        assert config["sequence"]["path"] == world["seq"]


def test_the_ninth_sets_templates_form(fresh) -> None:
    """Every case of studies/fresh_cases9.txt names known setups, has a known expectation, its
    argv and environment form with the world's paths (``${{...}}`` a literal interpolation),
    and each script has 18 to 30 cases."""
    cases = fresh.read_cases(STUDIES / "fresh_cases9.txt")
    names = ("W", "seq", "seq2", "voc", "ckpt", "onnx", "onnx2", "gt", "est", "vocab", "slam")
    paths = {**{n: f"/w/{n}" for n in names}, "C": "/c", "R": "/r", "tum": "/t", **fresh.LONG}
    assert len({c.id for c in cases}) == len(cases)
    expects = ("ok", "warn", "error", "pipe", "jobs")
    for case in cases:
        assert case.id.startswith(case.prog.removeprefix("uss-") + "9-"), case.id
        assert all(s in fresh.SETUPS for s in case.setup), case.id
        assert case.expect in expects or case.expect.startswith(fresh.SIGNALLED), case.id
        argv = fresh._argv(case, paths)
        assert not any("{" in a and "${" not in a for a in argv), case.id
        for value in case.env.values():
            value.format(**paths)
        for say in case.says:
            say.format(**paths)
        if "{big}" in case.argv:
            assert any(a.endswith("1" + "0" * 4400) for a in argv), case.id
        if "${{" in case.argv:
            assert any("${" in a and "${{" not in a for a in argv), case.id
    counts = Counter(c.prog for c in cases)
    assert len(counts) == 9 and all(18 <= n <= 30 for n in counts.values()), counts

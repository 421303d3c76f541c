"""The demo data set (``uss-demo``'s data stage): layout, summary, worker-independence, reuse of
a complete set with the same record, re-rendering otherwise."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines import demo, demo_data
from uss_slam.pipelines.demo_data import DemoData
from uss_slam.synthetic.output import OUTPUT_MARKER

SMALL = DemoData(voc_images=5, voc_size=(64, 48), train_frames=3, val_frames=2,
                 train_size=(48, 32), slam_frames=2, slam_size=(64, 48))  # fmt: skip

# demo.yaml of the ci plan as `uss-synth demo` wrote it: data sets rendered then stay reusable
CI_RECORD = """\
generator: uss-synth demo
seed: 0
voc_images: 8
voc_size:
- 320
- 240
train_frames: 4
val_frames: 4
train_size:
- 160
- 120
slam_frames: 30
slam_size:
- 320
- 240
"""


def test_record_is_unchanged_for_existing_data_sets() -> None:
    assert yaml.safe_dump(demo.PLANS["ci"].data.record(), sort_keys=False) == CI_RECORD
    assert demo.PLANS["demo"].data == DemoData()  # 400 images, 4 x 100, 100, 2 x 300 frames


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"voc_images": -1}, "voc_images must be >= 0"),
        ({"slam_frames": 1}, "slam_frames must be 0 (skip) or >= 2, got 1"),
        ({"train_size": (8, 8)}, "between 16x16"),
        ({"source_outfits": "bogus"}, "source_outfits must be one of classic, varied, got 'bogus'"),
    ],
)
def test_bad_spec(kwargs: dict, message: str) -> None:
    with pytest.raises(UssSlamError, match=message.replace("(", r"\(").replace(")", r"\)")):
        DemoData(**kwargs)


def test_source_outfits_record() -> None:
    """Classic data sets keep the record they always had (so they are reused); varied ones say so."""
    assert "source_outfits" not in DemoData().record()
    assert DemoData(source_outfits="varied").record()["source_outfits"] == "varied"
    assert DemoData(source_outfits="varied").record() != DemoData().record()


def test_small_data_set(tmp_path: Path) -> None:
    out = tmp_path / "data"
    demo_data.render_demo_data(out, SMALL, workers=1, progress=False)
    text = demo_data.summarize(out)
    assert str(out.resolve()) in text
    assert "voc/VOCdevkit/VOC2012: 4 train + 1 val images, 64x48" in text
    for name in demo_data.TRAIN_PRESETS:
        assert f"target_train/{name}: 3 frames, 48x32, target style" in text
        assert (out / "target_train" / name / "groundtruth.txt").is_file()
    assert "target_val/walking_xyz: 2 frames, 48x32" in text
    assert "slam/walking_xyz: 2 frames, 64x48" in text and "slam/static_xyz: 2 frames" in text
    assert "person" in text and "%" in text
    assert demo_data.is_complete(out, SMALL) and (out / OUTPUT_MARKER).is_file()
    assert not demo_data.is_complete(out, DemoData(voc_images=6, **_but(SMALL, "voc_images")))
    # two worker processes produce the same files
    again = tmp_path / "again"
    demo_data.render_demo_data(again, SMALL, workers=2, progress=False)
    files = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    assert all((out / f).read_bytes() == (again / f).read_bytes() for f in files)


def _but(spec: DemoData, name: str) -> dict:
    return {k: v for k, v in vars(spec).items() if k != name}


def test_stage_reuses_then_rerenders_on_another_spec(tmp_path: Path, capsys) -> None:
    out = tmp_path / "data"
    assert demo.stage_data(out, SMALL, force=False, quiet=True) == "rendered"
    assert "slam/walking_xyz: 2 frames" in capsys.readouterr().out
    stamp = (out / "slam" / "walking_xyz" / "rgb.txt").stat().st_mtime_ns
    assert demo.stage_data(out, SMALL, force=False, quiet=True) == "reused"
    assert "reusing the complete demo data set" in capsys.readouterr().out
    assert (out / "slam" / "walking_xyz" / "rgb.txt").stat().st_mtime_ns == stamp
    # another spec: rendered again, the old set replaced once the new one is complete
    other = DemoData(slam_frames=3, **_but(SMALL, "slam_frames"))
    assert demo.stage_data(out, other, force=False, quiet=True) == "rendered"
    assert (
        demo_data.is_complete(out, other) and "slam/static_xyz: 3 frames" in capsys.readouterr().out
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]
    # --force renders again even when complete
    assert demo.stage_data(out, other, force=True, quiet=True) == "rendered"


def test_stage_refuses_a_folder_that_is_not_a_data_set(tmp_path: Path) -> None:
    out = tmp_path / "data"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(UssSlamError, match="not a uss-synth output"):
        demo.stage_data(out, SMALL, force=False, quiet=True)
    assert [p.name for p in out.iterdir()] == ["notes.txt"]

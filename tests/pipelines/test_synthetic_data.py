"""The demo data set (``uss-demo``'s data stage): layout, summary, worker-independence, reuse of
a complete set with the same record, re-rendering otherwise."""

from __future__ import annotations

import gc
import warnings
from pathlib import Path

import pytest
import yaml

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines import demo, synthetic_data
from uss_slam.pipelines.synthetic_data import DemoData
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


def test_record_keeps_the_old_keys_and_names_the_validation_sequences(tmp_path: Path) -> None:
    """Data sets rendered before shifts existed are the ``full`` shift: the same keys in the same
    order, plus the validation sequences, which they lack (they had walking_xyz only), so they
    are rendered again rather than trained on without walking_rpy's validation frames; the
    default (``tum_like``) is another data set."""
    ci = demo.PLANS["ci"].data
    full = DemoData(**{**ci.__dict__, "shift": "full", "slam_seed": None})
    record = full.record()
    assert record.pop("val_sequences") == ["walking_xyz", "walking_rpy"]
    assert yaml.safe_dump(record, sort_keys=False) == CI_RECORD
    (tmp_path / "demo.yaml").write_text(CI_RECORD)
    assert not synthetic_data.is_complete(tmp_path, full)
    assert ci.record() == full.record() | {
        "source_outfits": "all",
        "shift": "tum_like",
        "source_near": 0.3,
        "slam_seed": demo.DEMO_SLAM_SEED,  # the demo's own SLAM renders
    }
    assert "val_sequences" not in DemoData(shift="appearance").record()  # image folders
    assert "val_sequences" not in DemoData(val_frames=0).record()
    assert demo.PLANS["demo"].data == DemoData(
        slam_seed=demo.DEMO_SLAM_SEED
    )  # 400 images, 4 x 100, 100, 2 x 300 frames
    assert DemoData().shift == "tum_like"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"voc_images": -1}, "voc_images must be >= 0"),
        ({"slam_frames": 1}, "slam_frames must be 0 (skip) or >= 2, got 1"),
        ({"train_size": (8, 8)}, "between 16x16"),
        (
            {"source_outfits": "bogus"},
            "source_outfits must be one of classic, varied, all, got 'bogus'",
        ),
        (
            {"shift": "style"},
            "shift: unknown shift 'style'; expected one of tum_like, appearance, full",
        ),
        (
            {"source_outfits": "varied"},
            "source_outfits=varied is the shift's to choose: shift tum_like",
        ),
    ],
)
def test_bad_spec(kwargs: dict, message: str) -> None:
    with pytest.raises(UssSlamError, match=message.replace("(", r"\(").replace(")", r"\)")):
        DemoData(**kwargs)


def test_source_outfits_record() -> None:
    """Classic data sets keep the record they always had (so they are reused); varied ones say so."""
    full = DemoData(shift="full")
    assert "source_outfits" not in full.record()
    varied = DemoData(shift="full", source_outfits="varied")
    assert varied.record()["source_outfits"] == "varied"
    assert varied.record() != full.record()


def test_shift_layouts(tmp_path: Path) -> None:
    """Each shift's target folders, and the overrides that point uss-train at them."""
    tum_like = DemoData()
    assert tum_like.target_folders() == [f"target_train/{p}" for p in synthetic_data.TRAIN_PRESETS]
    assert tum_like.val_folders() == ["target_val/walking_xyz", "target_val/walking_rpy"]
    assert tum_like.train_overrides(tmp_path) == []  # the shipped data=synthetic layout
    assert (tum_like.wardrobe, tum_like.sequence_outfits) == ("all", "drawn")
    assert (DemoData(shift="full").wardrobe, DemoData(shift="full").sequence_outfits) == (
        "classic", "office")  # fmt: skip
    appearance = DemoData(shift="appearance")
    assert appearance.target_folders() == [f"target_train/images_{k}" for k in range(4)]
    target, val = appearance.train_overrides(tmp_path)
    assert target == "data.target.roots=[" + ",".join(
        str(tmp_path / f"target_train/images_{k}") for k in range(4)) + "]"  # fmt: skip
    assert val == f"data.val.roots=[{tmp_path / 'target_val' / 'images'}]"


def test_appearance_data_set_is_the_source_content_in_target_style(tmp_path: Path) -> None:
    spec = DemoData(voc_images=3, voc_size=(64, 48), train_frames=2, val_frames=2,
                    train_size=(64, 48), slam_frames=0, shift="appearance")  # fmt: skip
    out = synthetic_data.render_demo_data(tmp_path / "data", spec, progress=False, workers=1)
    from uss_slam.datasets.tum import TUMFrames

    for folder in spec.target_folders() + spec.val_folders():
        assert not (out / folder / "depth.txt").exists()  # images, not a recording
        frames = TUMFrames([out / folder], labels=True)
        assert len(frames) == 2 and frames.labelled
    meta = yaml.safe_load((out / "target_val/images/synthetic.yaml").read_text())
    assert meta["style"] == "target" and meta["outfits"] == "classic"
    assert synthetic_data.is_complete(out, spec)


def test_small_data_set(tmp_path: Path) -> None:
    out = tmp_path / "data"
    synthetic_data.render_demo_data(out, SMALL, workers=1, progress=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)  # PYTHONWARNINGS=error shows them
        text = synthetic_data.summarize(out)
        gc.collect()
    assert not [w for w in caught if w.category is ResourceWarning], "a file left open"
    assert str(out.resolve()) in text
    assert "voc/VOCdevkit/VOC2012: 4 train + 1 val images, 64x48" in text
    for name in synthetic_data.TRAIN_PRESETS:
        assert f"target_train/{name}: 3 frames, 48x32, target style" in text
        assert (out / "target_train" / name / "groundtruth.txt").is_file()
    assert "target_val/walking_xyz: 2 frames, 48x32" in text
    assert "target_val/walking_rpy: 2 frames, 48x32" in text
    seeds = [yaml.safe_load((out / f / "synthetic.yaml").read_text())["seed"]
             for f in SMALL.val_folders()]  # fmt: skip
    assert seeds == [100, 101]  # seed + 100 + k: none a training sequence's
    assert "slam/walking_xyz: 2 frames, 64x48" in text and "slam/static_xyz: 2 frames" in text
    assert "person" in text and "%" in text
    assert synthetic_data.is_complete(out, SMALL) and (out / OUTPUT_MARKER).is_file()
    assert not synthetic_data.is_complete(out, DemoData(voc_images=6, **_but(SMALL, "voc_images")))
    # complete only while its outputs exist: a frame deleted since, then a VOC image
    frame = sorted((out / "slam" / "walking_xyz" / "rgb").iterdir())[1]
    kept = frame.read_bytes()
    frame.unlink()
    assert not synthetic_data.is_complete(out, SMALL)
    frame.write_bytes(kept)
    assert synthetic_data.is_complete(out, SMALL)
    # two worker processes produce the same files
    again = tmp_path / "again"
    synthetic_data.render_demo_data(again, SMALL, workers=2, progress=False)
    files = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    assert all((out / f).read_bytes() == (again / f).read_bytes() for f in files)
    sorted((out / "voc").rglob("JPEGImages/*.jpg"))[0].unlink()
    assert not synthetic_data.is_complete(out, SMALL)


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
        synthetic_data.is_complete(out, other)
        and "slam/static_xyz: 3 frames" in capsys.readouterr().out
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

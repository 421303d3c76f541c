"""The preparations of the ninth fresh set (``studies/fresh_cases9.txt``): what a user brings
from the tools of the field rather than from this project: a TUM sequence with the extra files
of TUM's downloads (``accelerometer.txt``); an ORB-SLAM settings file (``%YAML:1.0``,
``Camera.fx``) put in a sequence as its ``intrinsics.yaml``; the keyframe trajectory ORB-SLAM
writes (``KeyFrameTrajectory.txt``: every few frames' poses); a VOC tree as it is unpacked, with
``SegmentationObject/`` and JPEG images that no split lists; a primary config of the user's own
that starts from the shipped one (``defaults: [slam_eval, _self_]``, ``[experiments, _self_]``)
for ``--config-dir DIR --config-name mine``."""

from __future__ import annotations

import shutil
from pathlib import Path

from fresh_setups import Setup, _seq_edit

ORB_SLAM_SETTINGS = """%YAML:1.0

# Camera calibration and distortion parameters (OpenCV), as ORB-SLAM2's TUM1.yaml
Camera.fx: 517.306408
Camera.fy: 516.469215
Camera.cx: 318.643040
Camera.cy: 255.313989
Camera.k1: 0.262383
Camera.k2: -0.953104
Camera.p1: -0.005358
Camera.p2: 0.002628
Camera.k3: 1.163314
Camera.width: 640
Camera.height: 480
Camera.fps: 30.0
DepthMapFactor: 5000.0
"""
"""ORB-SLAM2's settings for TUM fr1 (the lines a user copies from ``Examples/RGB-D/TUM1.yaml``)."""

ACCELEROMETER = (
    "# accelerometer data\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp ax ay az\n"
)


def _tum_extras(seq: Path) -> None:
    """The files a TUM download holds beside the lists: ``accelerometer.txt`` (one row per
    colour frame's stamp)."""
    stamps = [r.split()[0] for r in (seq / "rgb.txt").read_text().splitlines()
              if r.strip() and not r.startswith("#")]  # fmt: skip
    rows = "".join(f"{s} -0.0888 7.2977 -6.0399\n" for s in stamps)
    (seq / "accelerometer.txt").write_text(ACCELEROMETER + rows)


def _orbslam_settings(seq: Path) -> None:
    (seq / "intrinsics.yaml").write_text(ORB_SLAM_SETTINGS)


def _keyframes(c: Path, world: dict[str, str]) -> None:
    """``{C}/KeyFrameTrajectory.txt``: every fifth pose of the world's estimate."""
    rows = [r for r in Path(world["est"]).read_text().splitlines()
            if r.strip() and not r.startswith("#")]  # fmt: skip
    (c / "KeyFrameTrajectory.txt").write_text("".join(r + "\n" for r in rows[::5]))


def _voc_as_unpacked(c: Path, world: dict[str, str]) -> None:
    """The world's VOC tree at ``{C}/voc`` with what VOC's archive holds besides: a
    ``SegmentationObject/`` (the instance masks, a copy of the class masks here) and JPEG
    images that no split lists (VOC has 17125 images, 2913 of them segmented)."""
    voc = c / "voc"
    shutil.copytree(world["voc"], voc)
    shutil.copytree(voc / "SegmentationClass", voc / "SegmentationObject")
    for i, jpg in enumerate(sorted((voc / "JPEGImages").iterdir())[:3]):
        shutil.copy(jpg, voc / "JPEGImages" / f"2012_9{i:05d}.jpg")
    (voc / "Annotations").mkdir()


def _primary(text: str) -> Setup:
    """``{C}/cfg/mine.yaml`` holding ``text`` formed with the world's paths."""

    def setup(c: Path, world: dict[str, str]) -> None:
        (c / "cfg").mkdir()
        (c / "cfg" / "mine.yaml").write_text(text.format(**world))

    return setup


NINTH: dict[str, Setup] = {
    "seq_tum_extras": _seq_edit(_tum_extras),
    "intr_orbslam_settings": _seq_edit(_orbslam_settings),
    "est_keyframes": _keyframes,
    "voc_unpacked": _voc_as_unpacked,
    "primary_slam": _primary(
        "defaults:\n  - slam_eval\n  - _self_\n\n"
        "sequence:\n  path: {seq}\n  max_frames: 10\nprogress: false\n"
    ),
    "primary_experiments": _primary(
        "defaults:\n  - experiments\n  - _self_\n\ndry_run: true\nsequences: [walking_xyz]\n"
    ),
}
"""Setup name -> preparation (``seqcopy`` first for ``seq_tum_extras``, ``intr_*``)."""

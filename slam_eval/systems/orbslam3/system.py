"""The real ORB-SLAM3 (RGB-D mode: tracking, local bundle adjustment, loop closing) as a second
SLAM system next to the harness: ``uss-slam system=orbslam3``.

It runs through the optional ``pyorbslam3`` bindings (GPL-3; ``pip install 'uss-slam[orbslam3]'``)
on the same TUM sequence reader, segmenters and evaluation as the harness, so that the numbers
are comparable:

- **Settings**: an ORB-SLAM3 settings file (OpenCV ``%YAML:1.0``, ``File.version: "1.0"``, as
  ORB-SLAM3's RGB-D TUM examples) is written from the sequence's :class:`CameraIntrinsics` and
  ``system.*`` (:func:`settings_yaml`); or ``system.settings_file`` names one of the user's.
  Either is checked here first (:func:`check_settings`): ORB-SLAM3 ends the process on a missing
  or mistyped key.
- **Dynamic objects**: ORB-SLAM3 takes no masks, so the segmenter's dynamic classes, dilated
  exactly as the harness's semantic filter (``slam.filter_params.semantic``: ``dynamic_classes``,
  ``dilation``), are *blanked* in its input (:func:`blank_dynamic`): the colour image is set to a
  flat grey (``system.blank_value``, default 128) and the depth to 0 there. A flat region has no
  FAST corners inside; only its border can, where it meets the image. Grey rather than black:
  the border's contrast against a typical scene is smaller, so fewer corners appear on the
  silhouette (walking_xyz: 126 ORB keypoints per frame within 10 px of the mask with grey 128,
  156 with black; ``benchmarks/orbslam3_blank_fill.py``). Corners centred inside the mask get
  no depth (no map point from a single frame); those just outside lie on what is behind the
  person, as the dilation reaches past its edge. ``segmenter=none`` blanks nothing.
- **Repeats**: ORB-SLAM3 runs its local mapping and loop closing in threads of its own and its
  results vary between runs of the same input; ``system.repeats`` (3) runs it that many times,
  each in a fresh Python process (ORB-SLAM3 keeps the first camera it saw in static members,
  and ends the process on some errors), and reports the ATE RMSE of the median run with the
  minimum and maximum. Every repeat's trajectory is kept (``repeats/trajectory_<i>.txt``); the
  median run's is ``trajectory.txt`` (for an even count, the lower of the two middle runs).
- **Untracked frames**: ORB-SLAM3's tracking state of every frame is counted (``OK``,
  ``RECENTLY_LOST``, ``LOST``, ``NOT_INITIALIZED`` ...); its trajectory
  (``SaveTrajectoryTUM``, after shutdown, so loop closures and bundle adjustment are in it) has no
  pose for lost frames: ``frames_without_pose`` counts them.
- **Vocabulary**: ``system.vocabulary``, a DBoW2 text vocabulary (``uss-vocab build`` makes a
  small one from frames; ORB-SLAM3's ``ORBvoc.txt`` works too). Nothing is downloaded.

Threads: besides the calling thread (tracking), ORB-SLAM3 starts its local-mapping and
loop-closing threads (and a global bundle adjustment thread after a loop closure); they cannot
be limited from here.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import math
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.tum_io import (
    CameraIntrinsics,
    StrPath,
    Trajectory,
    read_trajectory,
    write_trajectory,
)

from ...filters.dynamic import SemanticFilter
from ...scoring import plots
from ...scoring.report import STAT_KEYS, EvalConfig, Evaluation, evaluate
from ...segmenters.base import Segmenter
from ...sequence import TumSequence
from .vocabulary import read_header

log = logging.getLogger(__name__)

INSTALL_HINT = "pip install 'uss-slam[orbslam3]'"
VOCAB_HINT = (
    "build a small one from frames with `uss-vocab build --out vocab.txt SEQUENCE_DIR [...]` "
    "(or use ORB-SLAM3's ORBvoc.txt) and pass system.vocabulary=vocab.txt"
)
TRACKING_STATES = (
    "SYSTEM_NOT_READY",
    "NO_IMAGES_YET",
    "NOT_INITIALIZED",
    "OK",
    "RECENTLY_LOST",
    "LOST",
    "OK_KLT",
)
"""ORB-SLAM3's tracking states (``pyorbslam3.TrackingState``); only ``OK`` is tracked."""


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class OrbSlam3Config:
    """``system.*`` of ``configs/system/orbslam3.yaml`` (ORB-SLAM3's own settings)."""

    vocabulary: str | None = None
    """DBoW2 text vocabulary file (``uss-vocab build`` or ORB-SLAM3's ``ORBvoc.txt``)."""
    repeats: int = 3
    settings_file: str | None = None
    """An ORB-SLAM3 settings YAML to use instead of the one written from the sequence's camera."""
    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    ini_fast: int = 20
    min_fast: int = 7
    baseline: float = 0.0747
    """m, ``Stereo.b``: the virtual stereo baseline of RGB-D mode (TUM examples: bf = 40)."""
    th_depth: float = 40.0
    """``Stereo.ThDepth``: close points are nearer than ``th_depth × baseline`` (~3 m)."""
    fps: int | None = None
    """``Camera.fps`` (ORB-SLAM3 inserts a keyframe at least every fps frames); None = from
    the selected frames' stamps."""
    realtime: bool = True
    """Feed frames no faster than their stamps (as ORB-SLAM3's ``rgbd_tum`` example)."""
    blank_value: int = 128
    """Grey level (0-255) of the blanked dynamic pixels in the colour image."""

    def __post_init__(self) -> None:
        checks = [
            (self.repeats >= 1, "repeats", "an integer >= 1"),
            (self.n_features >= 1, "n_features", "an integer >= 1"),
            (self.scale_factor > 1.0, "scale_factor", "a number > 1"),
            (self.n_levels >= 1, "n_levels", "an integer >= 1"),
            (0 < self.min_fast <= self.ini_fast, "min_fast", "0 < min_fast <= ini_fast"),
            (self.baseline > 0, "baseline", "a number > 0 (metres)"),
            (self.th_depth > 0, "th_depth", "a number > 0"),
            (self.fps is None or self.fps >= 1, "fps", "null or an integer >= 1"),
            (0 <= self.blank_value <= 255, "blank_value", "a grey level 0..255"),
        ]
        for ok, key, expected in checks:
            if not ok:
                raise UssSlamError(f"system.{key}={getattr(self, key)!r}: expected {expected}")


# --------------------------------------------------------------------------- settings file

_VIEWER = {
    "Viewer.KeyFrameSize": 0.05,
    "Viewer.KeyFrameLineWidth": 1.0,
    "Viewer.GraphLineWidth": 0.9,
    "Viewer.PointSize": 2.0,
    "Viewer.CameraSize": 0.08,
    "Viewer.CameraLineWidth": 3.0,
    "Viewer.ViewpointX": 0.0,
    "Viewer.ViewpointY": -0.7,
    "Viewer.ViewpointZ": -1.8,
    "Viewer.ViewpointF": 500.0,
}
# What ORB-SLAM3's Settings class reads for an RGB-D pinhole camera, and the type it insists on.
_REQUIRED: dict[str, str] = {
    "Camera.type": "string",
    "Camera1.fx": "real",
    "Camera1.fy": "real",
    "Camera1.cx": "real",
    "Camera1.cy": "real",
    "Camera.width": "int",
    "Camera.height": "int",
    "Camera.fps": "int",
    "Camera.RGB": "int",
    "RGBD.DepthMapFactor": "real",
    "Stereo.ThDepth": "real",
    "Stereo.b": "real",
    "ORBextractor.nFeatures": "int",
    "ORBextractor.scaleFactor": "real",
    "ORBextractor.nLevels": "int",
    "ORBextractor.iniThFAST": "int",
    "ORBextractor.minThFAST": "int",
    **dict.fromkeys(_VIEWER, "real"),
}
_DISTORTION_KEYS = ("Camera1.k1", "Camera1.k2", "Camera1.p1", "Camera1.p2", "Camera1.k3")


def _real(value: float) -> str:
    """A float OpenCV's YAML reader takes as real (``500`` would read as an int)."""
    text = repr(float(value))
    return text if any(c in text for c in ".en") else text + ".0"


def settings_yaml(camera: CameraIntrinsics, config: OrbSlam3Config, fps: int) -> str:
    """ORB-SLAM3 RGB-D settings for ``camera`` (depth passed in metres: ``DepthMapFactor`` 1,
    colour passed in RGB order: ``Camera.RGB`` 1)."""
    if len(camera.distortion) not in (4, 5):
        raise UssSlamError(
            f"system=orbslam3: ORB-SLAM3's pinhole camera takes 4 or 5 distortion coefficients "
            f"(k1 k2 p1 p2 [k3]); the sequence's camera has {len(camera.distortion)}"
        )
    lines = [
        "%YAML:1.0",
        "# ORB-SLAM3 RGB-D settings written by uss-slam system=orbslam3 (TUM example layout)",
        'File.version: "1.0"',
        'Camera.type: "PinHole"',
        f"Camera1.fx: {_real(camera.fx)}",
        f"Camera1.fy: {_real(camera.fy)}",
        f"Camera1.cx: {_real(camera.cx)}",
        f"Camera1.cy: {_real(camera.cy)}",
    ]
    lines += [
        f"{key}: {_real(value)}"
        for key, value in zip(_DISTORTION_KEYS, camera.distortion, strict=False)
    ]
    lines += [
        f"Camera.width: {int(camera.width)}",
        f"Camera.height: {int(camera.height)}",
        f"Camera.fps: {int(fps)}",
        "Camera.RGB: 1",
        f"Stereo.ThDepth: {_real(config.th_depth)}",
        f"Stereo.b: {_real(config.baseline)}",
        "RGBD.DepthMapFactor: 1.0",
        f"ORBextractor.nFeatures: {int(config.n_features)}",
        f"ORBextractor.scaleFactor: {_real(config.scale_factor)}",
        f"ORBextractor.nLevels: {int(config.n_levels)}",
        f"ORBextractor.iniThFAST: {int(config.ini_fast)}",
        f"ORBextractor.minThFAST: {int(config.min_fast)}",
    ]
    lines += [f"{key}: {_real(value)}" for key, value in _VIEWER.items()]
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class SettingsInfo:
    """What the run needs to know of a checked settings file."""

    path: Path
    width: int
    height: int
    depth_factor: float
    """``RGBD.DepthMapFactor``: depth is passed as metres × this."""
    rgb: bool
    """``Camera.RGB``: colour is passed in RGB order if True, else BGR."""


def check_settings(path: StrPath, image_size: tuple[int, int] | None = None) -> SettingsInfo:
    """Check an ORB-SLAM3 RGB-D settings file the way ORB-SLAM3's ``Settings`` reads it.

    Raises :class:`DataFormatError` naming the file and the key for what ORB-SLAM3 would abort
    the process on: an unreadable file, no ``File.version: "1.0"``, a missing key or a value of
    the wrong type (``Camera.fps`` must be an integer, ...), a camera type other than PinHole, or
    an image size other than the sequence's ``image_size`` ``(width, height)``.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "file not found (system.settings_file)")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as err:  # OpenCV's parser errors surface as either
        text = str(err.__cause__ or err).strip()
        first = text.splitlines()[-1] if text else "parse error"
        raise DataFormatError(path, f"not an OpenCV YAML file ({first})") from None
    try:
        if not storage.isOpened():
            raise DataFormatError(path, "not an OpenCV YAML file")
        version = storage.getNode("File.version")
        if version.empty() or not version.isString() or version.string() != "1.0":
            raise DataFormatError(
                path, 'expected File.version: "1.0" (the ORB-SLAM3 settings format this reads)'
            )
        values: dict[str, Any] = {}
        for key, kind in _REQUIRED.items():
            node = storage.getNode(key)
            if node.empty():
                raise DataFormatError(path, f"missing {key} (ORB-SLAM3 requires it)")
            ok = {
                "string": node.isString(),
                "int": node.isInt(),
                "real": node.isReal() or node.isInt(),
            }[kind]
            if not ok:
                what = {"string": "a string", "int": "an integer", "real": "a number"}[kind]
                raise DataFormatError(path, f"{key} must be {what} (ORB-SLAM3 aborts otherwise)")
            values[key] = node.string() if kind == "string" else node.real()
        if values["Camera.type"] != "PinHole":
            raise DataFormatError(
                path, f'Camera.type must be "PinHole" for RGB-D, got {values["Camera.type"]!r}'
            )
        if not storage.getNode("Camera1.k1").empty():
            for key in _DISTORTION_KEYS[:4]:
                node = storage.getNode(key)
                if node.empty() or not (node.isReal() or node.isInt()):
                    raise DataFormatError(path, f"Camera1.k1 is set, so {key} must be a number")
    finally:
        storage.release()
    width, height = int(values["Camera.width"]), int(values["Camera.height"])
    if image_size is not None and (width, height) != tuple(image_size):
        raise DataFormatError(
            path,
            f"Camera.width x Camera.height is {width}x{height} but the sequence's images are "
            f"{image_size[0]}x{image_size[1]}",
        )
    factor = float(values["RGBD.DepthMapFactor"])
    if not factor > 0:
        raise DataFormatError(path, f"RGBD.DepthMapFactor must be > 0, got {factor}")
    return SettingsInfo(path, width, height, factor, bool(values["Camera.RGB"]))


def check_vocabulary(vocabulary: str | None) -> Path:
    """The vocabulary path, checked (exists, DBoW2 text header) before ORB-SLAM3 sees it."""
    if vocabulary is None or not str(vocabulary).strip():
        raise UssSlamError(f"system.vocabulary is not set: ORB-SLAM3 needs one; {VOCAB_HINT}")
    path = Path(str(vocabulary)).expanduser()
    if not path.is_file():
        raise UssSlamError(f"system.vocabulary={vocabulary}: file not found; {VOCAB_HINT}")
    try:
        read_header(path)
    except DataFormatError as err:
        raise UssSlamError(f"system.vocabulary={vocabulary}: {err.detail}") from None
    return path


def frame_rate(stamps: np.ndarray) -> int:
    """Frames per second from the median stamp spacing (at least 1)."""
    if len(stamps) < 2:
        return 30
    step = float(np.median(np.diff(stamps)))
    return max(1, round(1.0 / step)) if step > 0 else 30


# --------------------------------------------------------------------------- masking


def dynamic_mask(labels: np.ndarray, semantic: SemanticFilter) -> np.ndarray:
    """``(H, W)`` bool: the dynamic classes of ``labels``, dilated exactly as the harness's
    semantic filter does (:meth:`SemanticFilter.mask`)."""
    return semantic.mask(labels) > 0


def blank_dynamic(
    rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray | None, value: int = 128
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of ``rgb`` (H, W, 3) uint8 and ``depth`` (H, W) float32 with the ``mask`` pixels
    set to grey ``value`` and to depth 0 (no measurement); the inputs themselves when ``mask``
    is None or empty."""
    if mask is None or not mask.any():
        return rgb, depth
    rgb = rgb.copy()
    depth = depth.copy()
    rgb[mask] = value
    depth[mask] = 0.0
    return rgb, depth


@dataclass
class MaskPass:
    """The dynamic masks of every frame (packed bits, one row per frame) and their cost."""

    packed: np.ndarray
    shape: tuple[int, int]
    blanked_fraction: float
    """Mean fraction of the image blanked per frame."""
    segmentation_ms: float
    """Mean wall milliseconds of the segmenter per frame."""


def compute_masks(
    sequence: TumSequence, segmenter: Segmenter, semantic: SemanticFilter, progress: bool = True
) -> MaskPass:
    """Segment every frame once (shared by all repeats) and keep its dilated dynamic mask."""
    width, height = sequence.image_size
    packed = np.zeros((len(sequence), (width * height + 7) // 8), np.uint8)
    spent = 0.0
    blanked = 0
    frames = sequence.frames()
    try:
        for frame in tqdm(
            frames,
            total=len(sequence),
            desc=f"{sequence.path.name} [segmentation]",
            unit="frame",
            disable=not progress,
            dynamic_ncols=True,
        ):
            start = time.perf_counter()
            labels = segmenter.segment(frame)
            spent += time.perf_counter() - start
            if labels is None:
                raise UssSlamError(
                    f"segmenter {segmenter.name!r} returned no labels for frame {frame.index}"
                )
            mask = dynamic_mask(labels, semantic)
            blanked += int(mask.sum())
            packed[frame.index] = np.packbits(mask.reshape(-1))
    finally:
        frames.close()
    n = max(len(sequence), 1)
    return MaskPass(packed, (height, width), blanked / (n * width * height), 1000 * spent / n)


# --------------------------------------------------------------------------- one repeat


@dataclass
class RepeatResult:
    """One ORB-SLAM3 run: its trajectory, per-frame states and times."""

    index: int
    trajectory_path: Path
    trajectory: Trajectory
    states: list[str]
    track_s: float
    load_s: float
    evaluation: Evaluation | None = None

    @property
    def state_counts(self) -> dict[str, int]:
        counts = Counter(self.states)
        return {s: counts[s] for s in TRACKING_STATES if counts[s]}

    @property
    def ate_rmse(self) -> float | None:
        ate = self.evaluation.ate if self.evaluation else None
        return None if ate is None else float(ate.stats.rmse)


@dataclass(frozen=True)
class _Job:
    """What a worker process needs (written as JSON)."""

    sequence: dict[str, Any]
    vocabulary: str
    settings: str
    depth_factor: float
    rgb: bool
    masks: str | None
    blank_value: int
    realtime: bool
    trajectory: str
    result: str


def _run_worker(job: _Job, log_path: Path, workdir: Path, index: int) -> dict[str, Any]:
    """Run one repeat in a fresh Python process; its console output goes to ``log_path``."""
    job_path = workdir / f"job_{index}.json"
    job_path.write_text(json.dumps(asdict(job)))
    with open(log_path, "wb") as log_file:
        proc = subprocess.run(
            [sys.executable, "-m", "uss_slam.slam_eval.systems.orbslam3.system", str(job_path)],
            stdout=log_file,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            check=False,
        )
    result_path = Path(job.result)
    if proc.returncode != 0 or not result_path.is_file():
        tail = _last_line(log_path)
        how = (
            f"was killed by signal {-proc.returncode}"
            if proc.returncode < 0
            else f"exited with code {proc.returncode}"
        )
        raise UssSlamError(f"ORB-SLAM3 {how} in repeat {index} (log {log_path}): {tail}")
    return json.loads(result_path.read_text())


def _last_line(path: Path) -> str:
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return "no log"
    return lines[-1][:200] if lines else "no output"


def _worker(job_path: str) -> None:
    """The worker process: feed every frame to ORB-SLAM3, save its trajectory and states."""
    job = _Job(**json.loads(Path(job_path).read_text()))
    import pyorbslam3

    seq = TumSequence(job.sequence.pop("path"), **job.sequence)
    masks = np.load(job.masks) if job.masks else None
    height, width = seq.image_size[1], seq.image_size[0]
    start = time.perf_counter()
    slam = pyorbslam3.Slam(job.vocabulary, job.settings, pyorbslam3.Sensor.RGBD)
    loaded = time.perf_counter()
    stamps = seq.stamps
    states: list[str] = []
    frames = seq.frames()
    try:
        for frame in frames:
            tick = time.perf_counter()
            mask = None
            if masks is not None:
                bits = np.unpackbits(masks[frame.index], count=width * height)
                mask = bits.reshape(height, width).astype(bool)
            rgb, depth = blank_dynamic(frame.rgb, frame.depth, mask, job.blank_value)
            if not job.rgb:
                rgb = np.ascontiguousarray(rgb[:, :, ::-1])
            if job.depth_factor != 1.0:
                depth = depth * np.float32(job.depth_factor)
            result = slam.track_rgbd(rgb, depth, frame.stamp)
            states.append(result.state.name)
            if job.realtime:  # as ORB-SLAM3's rgbd_tum: wait until the next frame's time
                k = frame.index
                period = stamps[k + 1] - stamps[k] if k + 1 < len(stamps) else 0.0
                wait = period - (time.perf_counter() - tick)
                if wait > 0:
                    time.sleep(wait)
    finally:
        frames.close()
    tracked = time.perf_counter()
    slam.shutdown()
    if "OK" in states:  # ORB-SLAM3 saves relative to its first keyframe: none before init
        slam.save_trajectory_tum(job.trajectory)
    Path(job.result).write_text(
        json.dumps({"states": states, "track_s": tracked - loaded, "load_s": loaded - start})
    )


# --------------------------------------------------------------------------- the run


@dataclass(frozen=True)
class SequenceSpec:
    """How to open the sequence (``sequence.*`` of the config), for the worker processes too."""

    path: str
    camera: str | None = None
    max_diff: float = 0.02
    start: int = 0
    stride: int = 1
    max_frames: int | None = None

    def open(self, load_labels: bool = False) -> TumSequence:
        return TumSequence(
            self.path,
            camera=self.camera,
            max_diff=self.max_diff,
            load_labels=load_labels,
            start=self.start,
            stride=self.stride,
            max_frames=self.max_frames,
        )


def median_index(rmses: Sequence[float | None]) -> int:
    """Index of the median run by ATE RMSE (a run without ATE counts as the worst); for an
    even count the lower of the two middle runs, so the reported median is a real run's."""
    order = sorted(range(len(rmses)), key=lambda i: (math.inf if rmses[i] is None else rmses[i], i))
    return order[(len(order) - 1) // 2]


def run_orbslam3(
    spec: SequenceSpec,
    segmenter: Segmenter,
    semantic: SemanticFilter,
    config: OrbSlam3Config,
    evaluation: EvalConfig,
    out_dir: StrPath,
    *,
    settings: dict[str, Any] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run ORB-SLAM3 ``config.repeats`` times on the sequence and write the outputs to
    ``out_dir``: ``trajectory.txt`` (median run), ``repeats/trajectory_<i>.txt`` and
    ``repeats/orbslam3_<i>.log``, ``orbslam3_settings.yaml``, ``metrics.json``, ``report.md``,
    ``trajectory.png``, ``ate.png`` and ``repeats.png``. Returns the metrics dictionary."""
    if importlib.util.find_spec("pyorbslam3") is None:
        raise UssSlamError(
            f"system=orbslam3 needs the pyorbslam3 package (ORB-SLAM3 bindings, GPL-3): "
            f"{INSTALL_HINT}"
        )
    vocabulary = check_vocabulary(config.vocabulary)
    needs_labels = bool(getattr(segmenter, "needs_labels", False))
    sequence = spec.open(load_labels=needs_labels)
    out = Path(out_dir)
    (out / "repeats").mkdir(parents=True, exist_ok=True)
    fps = config.fps or frame_rate(sequence.stamps)
    if config.settings_file:
        info = check_settings(Path(config.settings_file).expanduser(), sequence.image_size)
    else:
        path = out / "orbslam3_settings.yaml"
        path.write_text(settings_yaml(sequence.camera, config, fps))
        info = check_settings(path, sequence.image_size)

    masked = getattr(segmenter, "name", "none") != "none"
    with tempfile.TemporaryDirectory(prefix="uss-orbslam3-") as tmp:
        workdir = Path(tmp)
        masks_file = None
        mask_pass = None
        if masked:
            mask_pass = compute_masks(sequence, segmenter, semantic, progress)
            masks_file = workdir / "masks.npy"
            np.save(masks_file, mask_pass.packed)
        results: list[RepeatResult] = []
        for i in range(config.repeats):
            trajectory_path = out / "repeats" / f"trajectory_{i}.txt"
            job = _Job(
                sequence=asdict(spec),
                vocabulary=str(vocabulary.resolve()),
                settings=str(info.path.resolve()),
                depth_factor=info.depth_factor,
                rgb=info.rgb,
                masks=None if masks_file is None else str(masks_file),
                blank_value=config.blank_value,
                realtime=config.realtime,
                trajectory=str(trajectory_path.resolve()),
                result=str(workdir / f"result_{i}.json"),
            )
            raw = _run_worker(job, out / "repeats" / f"orbslam3_{i}.log", workdir, i)
            trajectory = _read_estimate(trajectory_path)
            result = RepeatResult(
                i, trajectory_path, trajectory, raw["states"], raw["track_s"], raw["load_s"]
            )
            result.evaluation = evaluate(trajectory, sequence.groundtruth, evaluation)
            results.append(result)
            log.info(
                "orbslam3 repeat %d/%d: ATE RMSE %s m, %d/%d frames OK, %.1f frames/s",
                i + 1,
                config.repeats,
                "n/a" if result.ate_rmse is None else f"{result.ate_rmse:.4f}",
                result.state_counts.get("OK", 0),
                len(sequence),
                len(sequence) / result.track_s if result.track_s > 0 else 0.0,
            )
    return _write_outputs(
        out, sequence, segmenter, semantic, config, evaluation, info, fps, vocabulary,
        mask_pass, results, settings,
    )  # fmt: skip


def _read_estimate(path: Path) -> Trajectory:
    """ORB-SLAM3's saved trajectory; when it saved none (it never initialised, so no frame has a
    pose) an empty one is written in its place, so that every repeat has its file."""
    if not path.is_file():
        empty = Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)), path)
        write_trajectory(path, empty, comment="ORB-SLAM3 never initialised: no frame has a pose")
    return read_trajectory(path)


def _write_outputs(
    out: Path,
    sequence: TumSequence,
    segmenter: Segmenter,
    semantic: SemanticFilter,
    config: OrbSlam3Config,
    evaluation: EvalConfig,
    info: SettingsInfo,
    fps: int,
    vocabulary: Path,
    mask_pass: MaskPass | None,
    results: list[RepeatResult],
    settings: dict[str, Any] | None,
) -> dict[str, Any]:
    median = results[median_index([r.ate_rmse for r in results])]
    chosen = median.evaluation or Evaluation(None, None, None, "not evaluated")
    n = len(sequence)
    (out / "trajectory.txt").write_bytes(median.trajectory_path.read_bytes())
    rmses = [r.ate_rmse for r in results if r.ate_rmse is not None]
    header = read_header(vocabulary)
    data: dict[str, Any] = {
        "system": "orbslam3",
        "sequence": str(sequence.path),
        "camera": sequence.camera_source,
        "segmenter": getattr(segmenter, "name", "none"),
        "blanked": None
        if mask_pass is None
        else {
            "dynamic_classes": _class_names(semantic),
            "dilation": semantic.dilation,
            "grey": config.blank_value,
            "fraction": mask_pass.blanked_fraction,
            "segmentation_ms": mask_pass.segmentation_ms,
        },
        "frames": n,
        "unmatched_rgb_frames": sequence.unmatched_rgb,
        "frames_tracked": median.state_counts.get("OK", 0),
        "tracked_fraction": median.state_counts.get("OK", 0) / max(n, 1),
        "frames_without_pose": n - len(median.trajectory),
        "tracking_states": median.state_counts,
        "ate": chosen.ate.stats.as_dict() if chosen.ate else None,
        "rpe": _rpe(chosen.rpe, evaluation.rpe_delta, evaluation.rpe_unit),
        "rpe_1s": _rpe(chosen.rpe_1s, 1.0, "seconds"),
        "ate_error": chosen.error,
        "evaluation": {"max_diff": evaluation.max_diff, "align": evaluation.align},
        "ate_rmse_repeats": {
            "median": median.ate_rmse,
            "min": min(rmses) if rmses else None,
            "max": max(rmses) if rmses else None,
            "evaluated": len(rmses),
        },
        "median_repeat": median.index,
        "repeats": [
            {
                "index": r.index,
                "trajectory": str(r.trajectory_path.relative_to(out)),
                "ate_rmse": r.ate_rmse,
                "ate_error": r.evaluation.error if r.evaluation else None,
                "poses": len(r.trajectory),
                "tracking_states": r.state_counts,
                "track_s": r.track_s,
                "fps": n / r.track_s if r.track_s > 0 else None,
                "vocabulary_load_s": r.load_s,
            }
            for r in results
        ],
        "fps": float(np.median([n / r.track_s for r in results if r.track_s > 0] or [0.0])),
        "orbslam3": {
            "settings_file": str(info.path),
            "camera_fps": fps,
            "realtime": config.realtime,
            "vocabulary": str(vocabulary),
            "vocabulary_k_L": [header[0], header[1]],
            "pyorbslam3": _package_version("pyorbslam3"),
        },
    }
    if settings is not None:
        data["settings"] = settings
    (out / "metrics.json").write_text(json.dumps(data, indent=2) + "\n")
    figures = _plots(out, results, chosen, sequence)
    (out / "report.md").write_text(_report_md(data, figures))
    return data


def _class_names(semantic: SemanticFilter) -> list[str]:
    return [CLASS_NAMES[int(i)] for i in semantic.ids]


def _package_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def _rpe(result: Any, delta: float, unit: str) -> dict[str, Any] | None:
    if result is None:
        return None
    return {
        "trans": result.trans.as_dict(),
        "rot_deg": result.rot_deg.as_dict(),
        "delta": delta,
        "unit": unit,
    }


def _plots(
    out: Path, results: list[RepeatResult], chosen: Evaluation, sequence: TumSequence
) -> list[str]:
    if chosen.ate is None:
        return []
    a = chosen.ate
    title = sequence.path.name
    plots.plot_trajectories(
        out / "trajectory.png",
        a.gt_positions,
        [("ORB-SLAM3 (median run)", a.est_positions)],
        f"{title}: trajectory ({a.stats.pairs} poses, aligned)",
    )
    plots.plot_error_over_time(
        out / "ate.png", a.stamps, a.errors, f"{title}: absolute trajectory error"
    )
    estimates = [
        (f"repeat {r.index} ({r.ate_rmse:.4f} m)", r.evaluation.ate.est_positions)
        for r in results
        if r.evaluation is not None and r.evaluation.ate is not None
    ]
    plots.plot_trajectories(
        out / "repeats.png", a.gt_positions, estimates, f"{title}: every repeat (aligned)"
    )
    return ["trajectory.png", "ate.png", "repeats.png"]


def _fmt(value: float | None, digits: int = 4) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _report_md(data: dict[str, Any], figures: list[str]) -> str:
    blanked = data["blanked"]
    masking = (
        "none (segmenter=none)"
        if blanked is None
        else f"{', '.join(blanked['dynamic_classes'])} from segmenter {data['segmenter']}, dilated "
        f"{blanked['dilation']} px, blanked to grey {blanked['grey']} and depth 0 "
        f"({100 * blanked['fraction']:.1f}% of the pixels per frame on average; segmentation "
        f"{blanked['segmentation_ms']:.1f} ms per frame)"
    )
    rep = data["ate_rmse_repeats"]
    states = ", ".join(f"{k} {v}" for k, v in data["tracking_states"].items())
    lines = [
        f"# ORB-SLAM3 run: {Path(data['sequence']).name}",
        "",
        f"- sequence: `{data['sequence']}`; camera: {data['camera']}",
        f"- dynamic pixels: {masking}",
        f"- vocabulary: `{data['orbslam3']['vocabulary']}` (k={data['orbslam3']['vocabulary_k_L'][0]}, "
        f"L={data['orbslam3']['vocabulary_k_L'][1]}); settings: `{data['orbslam3']['settings_file']}`",
        f"- repeats: {len(data['repeats'])}; ATE RMSE median {_fmt(rep['median'])} m "
        f"(min {_fmt(rep['min'])}, max {_fmt(rep['max'])}; {rep['evaluated']} evaluated); "
        f"the median run is repeat {data['median_repeat']} (`trajectory.txt`)",
        f"- median run: {data['frames']} frames, {data['frames_tracked']} tracked (state OK, "
        f"{100 * data['tracked_fraction']:.1f}%); states: {states}; "
        f"{data['frames_without_pose']} frames without a pose in the trajectory; "
        f"{data['unmatched_rgb_frames']} colour frames without depth partner skipped",
        "",
        "## Trajectory error (median run)",
        "",
    ]
    if data["ate"] is None:
        lines += [f"Not evaluated: {data['ate_error']}", ""]
    else:
        lines += [
            "| | RMSE | Mean | Median | S.D. | Min | Max | pairs |",
            "|---|---|---|---|---|---|---|---|",
            "| ATE [m] | "
            + " | ".join(_fmt(data["ate"][k]) for k in STAT_KEYS)
            + f" | {data['ate']['pairs']} |",
        ]
        for key in ("rpe", "rpe_1s"):
            rpe = data[key]
            if rpe is None:
                continue
            unit = f"{rpe['delta']:g} {rpe['unit']}"
            for part, label, digits in (("trans", "trans [m]", 4), ("rot_deg", "rot [deg]", 3)):
                lines.append(
                    f"| RPE {label} / {unit} | "
                    + " | ".join(_fmt(rpe[part][k], digits) for k in STAT_KEYS)
                    + f" | {rpe[part]['pairs']} |"
                )
        lines += [
            "",
            f"Alignment: {data['evaluation']['align']}; association max difference "
            f"{data['evaluation']['max_diff']} s.",
            "",
        ]
    lines += [
        "## Repeats",
        "",
        "| repeat | ATE RMSE [m] | poses | frames OK | frames/s | trajectory |",
        "|---|---|---|---|---|---|",
    ]
    for r in data["repeats"]:
        lines.append(
            f"| {r['index']} | {_fmt(r['ate_rmse'])} | {r['poses']} | "
            f"{r['tracking_states'].get('OK', 0)} | {_fmt(r['fps'], 1)} | `{r['trajectory']}` |"
        )
    lines.append("")
    for figure in figures:
        lines += [f"![{figure}]({figure})", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- Hydra glue


def run_from_config(cfg: Any, out_dir: StrPath) -> dict[str, Any]:
    """``uss-slam system=orbslam3``: build everything from the composed config and run."""
    import hydra
    from omegaconf import OmegaConf

    if cfg.get("compare") is not None:
        raise UssSlamError(
            "system=orbslam3 runs one configuration per call; compare= is the harness's "
            "(run once with segmenter=none and once with segmenter=labels instead)"
        )
    if list(cfg.get("filters") or []):
        raise UssSlamError(
            f"system=orbslam3 takes no harness filters (got filters={list(cfg.filters)}): it "
            "blanks the segmenter's dynamic classes in its input instead; set segmenter=none "
            "for no masking"
        )
    if str(cfg.get("segment", "every_frame")) != "every_frame":
        raise UssSlamError(
            "system=orbslam3 segments every frame (its keyframe choice is internal); "
            "segment=keyframes applies to the harness only"
        )
    values = OmegaConf.to_container(cfg.system, resolve=True) or {}
    values.pop("name", None)
    try:
        config = OrbSlam3Config(**values)
    except TypeError as err:
        raise UssSlamError(f"system: {err}") from None
    seq = cfg.sequence
    spec = SequenceSpec(
        path=str(seq.path),
        camera=None if seq.camera is None else str(seq.camera),
        max_diff=float(seq.max_diff),
        start=int(seq.start),
        stride=int(seq.stride),
        max_frames=None if seq.max_frames is None else int(seq.max_frames),
    )
    params = OmegaConf.to_container(cfg.slam.filter_params.semantic, resolve=True) or {}
    try:
        semantic = SemanticFilter(**params)
    except TypeError as err:
        raise UssSlamError(f"slam.filter_params.semantic: {err}") from None
    ev = OmegaConf.to_container(cfg.eval, resolve=True) or {}
    try:
        evaluation = EvalConfig(**ev)
    except TypeError as err:
        raise UssSlamError(f"eval: {err}") from None
    segmenter: Segmenter = hydra.utils.instantiate(cfg.segmenter)
    data = run_orbslam3(
        spec,
        segmenter,
        semantic,
        config,
        evaluation,
        out_dir,
        settings=OmegaConf.to_container(cfg, resolve=True),
        progress=bool(cfg.get("progress", True)),
    )
    rep = data["ate_rmse_repeats"]
    log.info(
        "orbslam3: ATE RMSE median %s m (min %s, max %s) over %d repeats, %d/%d frames OK -> %s",
        _fmt(rep["median"]),
        _fmt(rep["min"]),
        _fmt(rep["max"]),
        len(data["repeats"]),
        data["frames_tracked"],
        data["frames"],
        out_dir,
    )
    return data


if __name__ == "__main__":  # the worker process of one repeat (see _run_worker)
    _worker(sys.argv[1])

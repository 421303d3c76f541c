"""TUM RGB-D sequences of the synthetic office: :class:`SequenceRenderer` and :func:`render_sequence`.

Time line (as the real recordings): colour frames at 30 Hz with a little jitter, depth stamps a
few milliseconds after their colour frame (depth is rendered registered to colour, at the colour
instant), and ground truth at 100 Hz on its own clock (never on an image stamp), covering the
images with a margin on both sides.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from uss_slam.core.progress import progress_bar
from uss_slam.core.tum_io import (
    KINECT_READOUT,
    TUM_CAMERAS,
    CameraIntrinsics,
    Trajectory,
    write_file_list,
    write_trajectory,
)

from .motion import PRESETS, CameraMotion, Preset
from .output import SynthArgumentError, check_size, staged_output, write_png
from .renderer import Renderer
from .scene import office_scene
from .seeding import stream
from .styles import (
    DEPTH_NOISE_K,
    EXPOSURE_TIME,
    STYLES,
    NoisePool,
    depth_to_png,
    exposure_gain,
    target_depth,
    target_rgb,
    to_uint8,
)
from .textures import texture_bank, walker_bank

SEQUENCE_OUTFITS = ("office", "drawn")
"""What a sequence's people wear: ``office`` = the outfits of the style's bank (slot ``k`` for
person ``k``: every sequence of a style shows the same ones); ``drawn`` = outfits drawn for this
sequence (its seed and preset) from the ``all`` wardrobe's distribution (:func:`walker_bank`)."""

TIMINGS = ("global", "rolling", "misregistered", "kinect")
"""Sensor timings of the target style: ``global`` renders colour, labels and depth at the
colour stamp; ``rolling`` reads the colour rows out over :data:`READOUT` seconds (row ``r`` at
the stamp + ``(r / (H - 1) - 0.5) * READOUT``: rolling-shutter skew, the labels with it);
``misregistered`` takes the depth image at its own stamp of ``depth.txt`` (3-12 ms after the
colour one: colour keypoints and their depth disagree while the camera turns); ``kinect``
both."""
READOUT = KINECT_READOUT
"""Seconds a ``kinect`` colour frame takes to read out, top row to bottom row (the readout
assumed for TUM's Kinects)."""
FPS = 30.0
GT_RATE = 100.0
START_STAMP = 1341846313.592026
"""First colour stamp (seconds): a plausible Unix time like the TUM recordings'."""
GT_PHASE = 0.0037
"""Offset of the ground-truth clock from the image clock, so no pose falls on an image stamp."""
GT_MARGIN = 0.3


@dataclass
class Frame:
    """One rendered frame. ``rgb`` (H, W, 3) uint8 RGB; ``depth`` (H, W) uint16 PNG units;
    ``labels`` (H, W) uint8 class ids; ``clean_depth`` (H, W) float32 exact metres (inf where
    nothing, before range limits and noise); ``pose`` 4×4 camera-to-world at ``stamp``."""

    index: int
    stamp: float
    depth_stamp: float
    rgb: np.ndarray
    depth: np.ndarray
    labels: np.ndarray
    clean_depth: np.ndarray
    pose: np.ndarray


def check_arguments(
    preset: str, frames: int, size: tuple[int, int], style: str, outfits: str = "office"
) -> Preset:
    if outfits not in SEQUENCE_OUTFITS:
        raise SynthArgumentError(
            f"unknown outfits {outfits!r}; choose one of {', '.join(SEQUENCE_OUTFITS)}"
        )
    if preset not in PRESETS:
        raise SynthArgumentError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 2:
        raise SynthArgumentError(f"frames must be an integer >= 2, got {frames!r}")
    check_size(size)
    if style not in STYLES:
        raise SynthArgumentError(f"unknown style {style!r}; choose one of {', '.join(STYLES)}")
    return PRESETS[preset]


class SequenceRenderer:
    """Renders the frames of one sequence in any order (everything is a function of time)."""

    def __init__(
        self,
        preset: str,
        frames: int,
        size: tuple[int, int] = (640, 480),
        seed: int = 0,
        style: str = "target",
        outfits: str = "office",
        timing: str | None = None,
    ) -> None:
        self.preset = check_arguments(preset, frames, size, style, outfits)
        self.outfits = outfits
        self.timing = self.preset.timing if timing is None else timing
        if self.timing not in TIMINGS:
            raise SynthArgumentError(
                f"unknown timing {self.timing!r}; choose one of {', '.join(TIMINGS)}"
            )
        self.frames = int(frames)
        self.size = check_size(size)
        self.seed = int(seed)
        self.style = style
        # the camera declares its readout when its rows are read out one after the other
        rolling = style == "target" and self.timing in ("rolling", "kinect")
        self.camera: CameraIntrinsics = replace(
            TUM_CAMERAS["fr3"].scaled(*self.size), readout=READOUT if rolling else None
        )
        self.renderer = Renderer(self.camera)
        duration = self.frames / FPS + 1.0
        self.scene = office_scene(self.seed, self.preset.people, duration, self.preset.motion)
        self.motion = CameraMotion(self.preset.motion, self.scene.eye, self.scene.target, self.seed)
        # one set of room materials per style, like one real office; the people's per sequence
        # with outfits="drawn"
        if outfits == "drawn":
            self.bank = walker_bank(style, self.seed, preset)
        else:
            self.bank = texture_bank(style)
        self.lighting = self.scene.lighting(style)

        rng = stream(self.seed, "stamps")
        jitter = rng.uniform(-0.0015, 0.0015, self.frames)
        stamps = START_STAMP + np.arange(self.frames) / FPS + jitter
        # stamps as written (6 decimals) are the instants rendered, so files agree exactly
        self.stamps = np.round(stamps, 6)
        # ground truth stamps have 4 decimals: keep the 5th-6th image decimals non-zero so that
        # no image stamp can ever coincide with a ground-truth stamp
        on_grid = np.rint(self.stamps * 1e6).astype(np.int64) % 100 == 0
        self.stamps[on_grid] += 1e-6
        self.depth_stamps = np.round(self.stamps + rng.uniform(0.003, 0.012, self.frames), 6)
        self.exposure_phase = float(stream(self.seed, "exposure").uniform(0, 2 * np.pi))
        w, h = self.size
        self.noise = NoisePool(self.seed, 2 * w * h * 3 + 4096) if style == "target" else None

    def time(self, stamp: float) -> float:
        """Seconds since the first frame (the clock of the scene and camera motion)."""
        return float(stamp - START_STAMP)

    def pose(self, stamp: float) -> np.ndarray:
        return self.motion.pose(self.time(stamp))

    def frame(self, index: int) -> Frame:
        stamp = float(self.stamps[index])
        t = self.time(stamp)
        pose = self.motion.pose(t)
        res = self.renderer.render(pose, self.scene.room, self.scene.prims_at(t), self.bank,
                                   self.lighting)  # fmt: skip
        if self.style == "source":
            rgb = to_uint8(res.rgb)
            depth = depth_to_png(res.depth)
        else:
            rng = stream(self.seed, "noise", index)
            # the exposure is centred on the stamp: blur from half an exposure before to after
            before = self.motion.pose(t - EXPOSURE_TIME / 2)
            flow = self.renderer.flow(res.depth, pose, before)
            gain = exposure_gain(t, self.exposure_phase)
            colour, labels, metres = res.rgb, res.labels, res.depth
            if self.timing != "global":
                colour, labels, metres = self._sensor_timing(res, pose, t, index)
            rgb = target_rgb(colour, flow, gain, rng, self.noise)
            depth = target_depth(metres, rng, self.noise)
            res = replace(res, labels=labels)
        return Frame(index, stamp, float(self.depth_stamps[index]), rgb, depth, res.labels,
                     res.depth, pose)  # fmt: skip

    def _sensor_timing(
        self, res: Any, pose: np.ndarray, t: float, index: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Colour and labels with rolling-shutter skew and / or the depth as seen at the depth
        stamp (:data:`TIMINGS`), from the render at the colour stamp. Each is a backward warp
        along the static scene's image motion (first order: what a row saw ``tau`` later is
        where the render's point moves in ``tau``)."""
        h, w = res.labels.shape
        xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        colour, labels, metres = res.rgb, res.labels, res.depth
        if self.camera.readout:
            # the bottom row is read READOUT / 2 after the stamp, the top row as long before
            half = self.renderer.flow(res.depth, pose, self.motion.pose(t + READOUT / 2))
            skew = (2 * ys / np.float32(max(h - 1, 1)) - 1)[..., None] * half
            mx, my = xs - skew[..., 0], ys - skew[..., 1]
            colour = cv2.remap(colour, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            labels = cv2.remap(labels, mx, my, cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
        if self.timing == "rolling":
            return colour, labels, metres
        t_depth = self.time(float(self.depth_stamps[index]))
        shift = self.renderer.flow(res.depth, pose, self.motion.pose(t_depth))
        metres = cv2.remap(res.depth, xs - shift[..., 0], ys - shift[..., 1], cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)  # fmt: skip
        return colour, labels, metres

    def groundtruth(self) -> Trajectory:
        """Camera-to-world poses at 100 Hz from before the first to after the last frame."""
        first = self.stamps[0] - GT_MARGIN + GT_PHASE
        count = int(np.floor((self.stamps[-1] + GT_MARGIN - first) * GT_RATE)) + 1
        gt_stamps = np.round(first + np.arange(count) / GT_RATE, 4)
        poses = np.stack([self.pose(s) for s in gt_stamps])
        return Trajectory.from_matrices(gt_stamps, poses)


def render_sequence(
    out_dir: str | PathLike[str],
    *,
    preset: str,
    frames: int,
    size: tuple[int, int] = (640, 480),
    seed: int = 0,
    style: str = "target",
    outfits: str = "office",
    timing: str | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> Path:
    """Render a TUM RGB-D sequence folder and return its path.

    Writes ``rgb/`` (uint8 PNG), ``depth/`` (uint16 PNG, 5000 = 1 m, 0 = none), ``labels/``
    (uint8 class-id PNG, same names as ``rgb/``), ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``
    (100 Hz, camera-to-world, optical frame), ``intrinsics.yaml`` (fr3 scaled to ``size``; the target style declares its depth noise) and
    ``synthetic.yaml`` (the arguments). The folder appears only when complete; an existing
    non-empty ``out_dir`` is an error unless ``overwrite``. ``outfits``: what the people wear
    (:data:`SEQUENCE_OUTFITS`). ``timing``: the target style's sensor timing
    (:data:`TIMINGS`; None = the preset's).
    """
    seq = SequenceRenderer(preset, frames, size, seed, style, outfits, timing)
    with staged_output(out_dir, overwrite) as tmp:
        for sub in ("rgb", "depth", "labels"):
            (tmp / sub).mkdir()
        rgb_files, depth_files = [], []
        bar = progress_bar(
            range(seq.frames), desc=f"{preset} ({style})", unit="frame", disable=not progress
        )
        for i in bar:
            fr = seq.frame(i)
            name = f"{fr.stamp:.6f}.png"
            dname = f"{fr.depth_stamp:.6f}.png"
            write_png(tmp / "rgb" / name, fr.rgb)
            write_png(tmp / "labels" / name, fr.labels)
            write_png(tmp / "depth" / dname, fr.depth)
            rgb_files.append(f"rgb/{name}")
            depth_files.append(f"depth/{dname}")
        write_file_list(tmp / "rgb.txt", seq.stamps, rgb_files, "color images")
        write_file_list(tmp / "depth.txt", seq.depth_stamps, depth_files, "depth maps")
        write_trajectory(
            tmp / "groundtruth.txt",
            seq.groundtruth(),
            comment=f"ground truth trajectory (uss-synth {preset}, seed {seed})",
        )
        # the target style's depth noise is known exactly: declared for the SLAM back end
        noise = DEPTH_NOISE_K if style == "target" else None
        replace(seq.camera, depth_noise=noise).to_yaml(tmp / "intrinsics.yaml")
        meta = {
            "generator": "uss-synth",
            "preset": preset,
            "description": seq.preset.description,
            "frames": seq.frames,
            "size": list(seq.size),
            "seed": seq.seed,
            "style": style,
            **({"outfits": outfits} if outfits != "office" else {}),
            **({"timing": seq.timing} if seq.timing != "global" and style == "target" else {}),
            "fps": FPS,
            "groundtruth_rate": GT_RATE,
        }
        (tmp / "synthetic.yaml").write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
    return Path(out_dir)

"""Camera motions and the sequence presets named after the TUM RGB-D sequences.

Every motion is a smooth function of time (seconds), so ground truth can be sampled at any rate
(100 Hz, off the image stamps) and agrees exactly with the rendered frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .primitives import rot_x, rot_y, rot_z
from .seeding import stream

LOOP_PERIOD = 12.0
"""Seconds per turn of the ``loop`` motion (360 frames at 30 Hz)."""
LOOP_MIN_FRAMES = int(LOOP_PERIOD * 30) + 90
"""The ``loop`` preset's fewest frames: one turn and 3 s more (450)."""
LOOP_RADIUS = 0.3
"""Radius of the ``loop`` motion's circle, metres."""
MOTIONS = ("xyz", "static", "rpy", "halfsphere", "loop", "handheld", "handheld_fast")
"""The camera motion kinds (:attr:`Preset.motion`)."""
FAST_HANDHELD = 4.0
"""``handheld_fast`` is ``handheld``'s path (same seed, same poses) run this many times faster:
up to ~300 deg/s, ~155 on average (``handheld``: up to ~80, ~40)."""


@dataclass(frozen=True)
class Preset:
    """A sequence recipe: how the camera moves and what the people do."""

    name: str
    motion: str  # one of MOTIONS
    people: str  # "walking", "sitting", "frozen"
    description: str
    timing: str = "global"
    """The target style's sensor timing by default (``uss-synth sequence --timing``):
    ``global`` (every pixel and the depth at the colour stamp) or ``kinect`` (a rolling
    shutter, and the depth image at its own stamp: :data:`~.sequence.TIMINGS`)."""
    min_frames: int = 2
    """The fewest frames (at 30 Hz) that show what the preset is for (``uss-synth`` refuses
    fewer: ``--frames``)."""
    min_frames_reason: str = ""
    """Why :attr:`min_frames`, in a few words (the refusal's line)."""


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset("walking_xyz", "xyz", "walking",
               "camera translated along its x, y, z axes; two people walk slowly across the view close to the camera"),
        Preset("walking_static", "static", "walking",
               "camera almost still; two people walk through the view"),
        Preset("walking_rpy", "rpy", "walking",
               "camera rotated about its axes in place (roll, pitch, yaw); two people walk"),
        Preset("walking_halfsphere", "halfsphere", "walking",
               "camera moved on a half sphere of ~1 m diameter; two people walk"),
        Preset("sitting_static", "static", "sitting",
               "camera almost still; two seated people gesture and turn their heads"),
        Preset("static_xyz", "xyz", "frozen",
               "control: camera translated along its axes; two seated people who never move"),
        Preset("loop", "loop", "frozen",
               "camera tours the room on a circle looking outwards, back at its start every "
               f"{LOOP_PERIOD:g} s (loop closing; >= {LOOP_MIN_FRAMES} frames)",
               min_frames=LOOP_MIN_FRAMES,
               min_frames_reason=f"one turn of {LOOP_PERIOD:g} s at 30 Hz and 3 s back over "
                                 "the start, for the loop to be seen again"),
        Preset("handheld_rpy", "handheld", "frozen",
               "control with handheld motion (like TUM fr1/fr2 rpy): fast roll, pitch and yaw "
               "(up to ~60 deg/s, ~40 on average) with hand shake and a few cm of drift, a rolling "
               "shutter and depth taken at its own instant; two seated people who never move",
               timing="kinect"),
        Preset("handheld_fast", "handheld_fast", "frozen",
               f"handheld_rpy's path {FAST_HANDHELD:g}x faster: up to ~300 deg/s (~155 on "
               "average, 5 deg between frames, 10 at the peaks), for tracking at large steps; "
               "two seated people who never move", timing="kinect"),
    )
}  # fmt: skip
"""The presets by name (``uss-synth sequence --preset NAME``)."""


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world rotation (optical frame: x right, y down, z ahead) looking at ``target``."""
    f = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    f /= np.linalg.norm(f)
    right = np.cross(f, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    down = np.cross(f, right)
    return np.stack([right, down, f], axis=1)


class CameraMotion:
    """Camera-to-world pose as a function of time for one of the motion kinds of :data:`PRESETS`.

    ``eye`` / ``target``: the rest position and the point it looks at (world metres).
    """

    def __init__(self, kind: str, eye: np.ndarray, target: np.ndarray, seed: int) -> None:
        if kind not in MOTIONS:
            raise ValueError(f"unknown camera motion {kind!r}")
        self.kind = kind
        self.speed = FAST_HANDHELD if kind == "handheld_fast" else 1.0
        """Time factor of the motion (``handheld_fast`` runs ``handheld``'s path faster)."""
        kind = "handheld" if kind == "handheld_fast" else kind
        self.eye = np.asarray(eye, np.float64)
        self.target = np.asarray(target, np.float64)
        self.base = look_at(self.eye, self.target)
        rng = stream(seed, f"camera/{kind}")
        self.phase = rng.uniform(0, 2 * np.pi, 6)
        self.period = rng.uniform(0.9, 1.1, 6)
        if kind == "handheld":  # a stream of its own: the other motions stay as they were
            shake = stream(seed, "camera/handheld/shake")
            self.shake_phase = shake.uniform(0, 2 * np.pi, 6)
            self.shake_period = shake.uniform(0.9, 1.1, 6)

    def _wave(self, t: float, i: int, period: float) -> float:
        return math.sin(2 * math.pi * t / (period * self.period[i]) + self.phase[i])

    def _shake(self, t: float, i: int, period: float) -> float:
        return math.sin(2 * math.pi * t / (period * self.shake_period[i]) + self.shake_phase[i])

    def pose(self, t: float) -> np.ndarray:
        """The 4×4 camera-to-world matrix at ``t`` seconds."""
        t = t * self.speed
        w = self._wave
        out = np.eye(4)
        rot = self.base
        pos = self.eye.copy()
        if self.kind in ("xyz", "static"):
            amp = (0.24, 0.12, 0.2) if self.kind == "xyz" else (0.006, 0.004, 0.005)
            wob = math.radians(0.6 if self.kind == "xyz" else 0.25)
            offset = np.array([amp[0] * w(t, 0, 5.7), amp[1] * w(t, 1, 7.3), amp[2] * w(t, 2, 9.1)])
            pos = pos + self.base @ offset
            rot = rot @ rot_x(wob * w(t, 3, 3.1)) @ rot_y(wob * w(t, 4, 4.3))
        elif self.kind == "rpy":
            roll = math.radians(10) * w(t, 0, 6.3)
            pitch = math.radians(8) * w(t, 1, 7.7)
            yaw = math.radians(15) * w(t, 2, 8.9)
            # camera axes: z ahead (roll), x right (pitch), y down (yaw)
            rot = rot @ rot_y(yaw) @ rot_x(pitch) @ rot_z(roll)
            pos = pos + self.base @ (0.01 * np.array([w(t, 3, 4.1), w(t, 4, 5.3), w(t, 5, 6.7)]))
        elif self.kind in ("handheld", "handheld_fast"):
            # A hand-held camera swept about its axes (TUM fr1/rpy): slow swings of 11-17 deg
            # plus a faster hand shake, so each axis turns at up to ~35 (roll), ~45 (pitch) and
            # ~60 deg/s (yaw), ~40 deg/s on average; the hand drifts a few cm, trembles 2 mm.
            roll = math.radians(11) * w(t, 0, 3.7) + math.radians(2.2) * self._shake(t, 0, 0.93)
            pitch = math.radians(12) * w(t, 1, 2.9) + math.radians(2.4) * self._shake(t, 1, 0.71)
            yaw = math.radians(17) * w(t, 2, 3.3) + math.radians(3.3) * self._shake(t, 2, 0.83)
            rot = rot @ rot_y(yaw) @ rot_x(pitch) @ rot_z(roll)
            drift = 0.03 * np.array([w(t, 3, 4.3), w(t, 4, 5.1), w(t, 5, 6.2)])
            tremble = 0.002 * np.array(
                [self._shake(t, k, p) for k, p in ((3, 0.47), (4, 0.53), (5, 0.61))]
            )
            pos = pos + self.base @ (drift + tremble)
        elif self.kind == "loop":
            # On a circle 1.5 m ahead of the eye (mid-room), looking outwards and a little down,
            # one turn every LOOP_PERIOD: the whole room passes by, then the start view again.
            forward = self.base[:, 2].copy()
            forward[2] = 0.0
            forward /= np.linalg.norm(forward)
            angle = 2 * math.pi * t / LOOP_PERIOD
            heading = rot_z(angle) @ forward
            pos = self.eye + (1.5 - LOOP_RADIUS) * forward + LOOP_RADIUS * heading
            rot = look_at(pos, pos + 2.0 * heading + np.array([0.0, 0.0, -0.45]))
        else:  # halfsphere: radius 0.5 m around a centre half a metre ahead of the eye
            forward = self.base[:, 2]
            right = self.base[:, 0]
            up = np.array([0.0, 0.0, 1.0])
            centre = self.eye + 0.5 * forward
            az = math.radians(65) * w(t, 0, 11.0)
            el = math.radians(22) + math.radians(28) * w(t, 1, 7.3)
            direction = (
                -forward * math.cos(el) * math.cos(az)
                + right * math.cos(el) * math.sin(az)
                + up * math.sin(el)
            )
            pos = centre + 0.5 * direction
            rot = look_at(pos, self.target)
        out[:3, :3] = rot
        out[:3, 3] = pos
        return out

"""People built from primitives, and what they do over time (walk, turn, stand, sit).

A person is 14 primitives (pelvis, torso, head, hair, thighs, shins, feet, upper arms, forearms)
posed by a few joint angles. :class:`Behaviour` is a timeline of segments (walk along a closed
path, pause and turn, sit down on a chair and get up, stay seated) that gives the body pose at any
time, so that poses are a smooth function of time and frames can be rendered in any order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from uss_slam.core.classes import CLASS_NAMES

from .primitives import Prim, box, cylinder, ellipsoid, rot_y, rot_z
from .textures import material

PERSON = CLASS_NAMES.index("person")
SEAT_HEIGHT = 0.44
"""Top of a chair seat (metres); a seated pelvis rests on it."""
SIT_TIME = 1.3
"""Seconds to sit down or to get up."""
TURN_RATE = 2.5
"""Radians per second of an in-place turn."""
SIT_EVERY = 25.0
"""Seconds between the end of one sit-down of a walking person and the next."""


@dataclass(frozen=True)
class Outfit:
    """Materials and build of one person."""

    slot: int
    height: float = 1.75
    shirt_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    trousers_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @property
    def scale(self) -> float:
        return self.height / 1.75


@dataclass(frozen=True)
class BodyPose:
    """Where a person is and how the limbs are posed.

    ``x, y`` the pelvis over the floor (metres); ``heading`` facing direction (radians from +x);
    ``phase`` gait phase (radians) and ``gait`` its amplitude (0 still .. 1 walking);
    ``sit`` 0 standing .. 1 seated; ``lean`` torso pitch forward; ``head_yaw``; ``arms``
    extra forward pitch of the left / right arm (gestures).
    """

    x: float
    y: float
    heading: float
    phase: float = 0.0
    gait: float = 0.0
    sit: float = 0.0
    lean: float = 0.0
    head_yaw: float = 0.0
    arms: tuple[float, float] = (0.0, 0.0)


def body_prims(pose: BodyPose, outfit: Outfit) -> list[Prim]:
    """The 14 primitives of a person in world coordinates (z up, floor at 0)."""
    s = outfit.scale
    thigh, shin, foot_h = 0.44 * s, 0.44 * s, 0.04 * s
    # Sitting: thighs rotate forward to horizontal while the knee bends by the same angle, so the
    # shins stay vertical and the pelvis lowers from standing height to the seat.
    theta_sit = pose.sit * math.pi / 2
    g = pose.gait
    swing = 0.42 * g * math.sin(pose.phase)
    knee_l = 0.08 * g + 0.65 * g * max(0.0, math.cos(pose.phase))
    knee_r = 0.08 * g + 0.65 * g * max(0.0, -math.cos(pose.phase))
    hip_z = thigh * math.cos(theta_sit) + shin + foot_h
    hip_z += 0.015 * g * abs(math.cos(pose.phase))  # bob
    if pose.sit > 0.98:
        hip_z = max(hip_z, SEAT_HEIGHT + 0.06 * s)

    world_rot = rot_z(pose.heading)
    origin = np.array([pose.x, pose.y, 0.0])

    def w(p) -> np.ndarray:
        return origin + world_rot @ np.asarray(p, np.float64)

    def limb_dir(pitch: float) -> np.ndarray:
        # pitch 0 points down; positive swings forward (+x of the body)
        return np.array([math.sin(pitch), 0.0, -math.cos(pitch)])

    prims: list[Prim] = []
    trousers = material(f"trousers_{outfit.slot}")
    shirt = material(f"shirt_{outfit.slot}")
    skin = material(f"skin_{outfit.slot}")
    hair = material(f"hair_{outfit.slot}")
    shoe_tint = tuple(0.35 * c for c in outfit.trousers_tint)

    for side, sign in (("l", 1.0), ("r", -1.0)):
        leg_swing = swing if side == "l" else -swing
        knee_bend = knee_l if side == "l" else knee_r
        pitch_thigh = theta_sit + (1 - pose.sit) * leg_swing
        pitch_shin = pitch_thigh - theta_sit * 1.0 - (1 - pose.sit) * knee_bend
        hip = np.array([0.0, sign * 0.095 * s, hip_z])
        knee = hip + thigh * limb_dir(pitch_thigh)
        ankle = knee + shin * limb_dir(pitch_shin)
        prims.append(cylinder(w(hip), w(knee), 0.075 * s, PERSON, trousers, outfit.trousers_tint))
        prims.append(cylinder(w(knee), w(ankle), 0.06 * s, PERSON, trousers, outfit.trousers_tint))
        foot_c = ankle + np.array([0.06 * s, 0.0, -0.5 * foot_h])
        foot_c[2] = max(foot_c[2], 0.5 * foot_h)
        prims.append(
            box(w(foot_c), (0.24 * s, 0.09 * s, foot_h), PERSON, trousers, world_rot, shoe_tint)
        )

    # Torso, neck and head pitch about the hip by the lean angle (plus a lean back when seated).
    lean = pose.lean - 0.12 * pose.sit
    torso_rot = rot_y(lean)
    hip_c = np.array([0.0, 0.0, hip_z])

    def t(p) -> np.ndarray:
        return hip_c + torso_rot @ np.asarray(p, np.float64)

    prims.append(
        ellipsoid(w(t((0, 0, 0.06 * s))), np.array([0.11, 0.17, 0.12]) * s, PERSON, trousers,
                  world_rot @ torso_rot, outfit.trousers_tint)
    )  # fmt: skip
    prims.append(
        ellipsoid(w(t((0, 0, 0.34 * s))), np.array([0.13, 0.21, 0.30]) * s, PERSON, shirt,
                  world_rot @ torso_rot, outfit.shirt_tint)
    )  # fmt: skip
    head_rot = world_rot @ torso_rot @ rot_z(pose.head_yaw)
    head_c = t((0, 0, 0.76 * s))
    prims.append(ellipsoid(w(head_c), np.array([0.1, 0.085, 0.12]) * s, PERSON, skin, head_rot))
    prims.append(
        ellipsoid(w(head_c + torso_rot @ np.array([-0.02, 0, 0.035]) * s),
                  np.array([0.1, 0.09, 0.1]) * s, PERSON, hair, head_rot)
    )  # fmt: skip

    for side, sign in (("l", 1.0), ("r", -1.0)):
        arm_swing = -swing * 0.8 if side == "l" else swing * 0.8
        gesture = pose.arms[0] if side == "l" else pose.arms[1]
        # seated people rest their forearms forward (on a desk or the lap)
        pitch_upper = (1 - pose.sit) * arm_swing + pose.sit * 0.35 + gesture + lean
        pitch_fore = pitch_upper + 0.2 + 0.2 * g + pose.sit * 0.9 + 0.8 * gesture
        shoulder = t((0, sign * 0.2 * s, 0.56 * s))
        elbow = shoulder + 0.3 * s * limb_dir(pitch_upper)
        wrist = elbow + 0.27 * s * limb_dir(pitch_fore)
        prims.append(cylinder(w(shoulder), w(elbow), 0.05 * s, PERSON, shirt, outfit.shirt_tint))
        prims.append(cylinder(w(elbow), w(wrist), 0.042 * s, PERSON, shirt, outfit.shirt_tint))
    return prims


# --------------------------------------------------------------------------- paths


class LoopPath:
    """A closed path on the floor (ellipse ``center ± (ax, ay)``) parametrised by arc length."""

    def __init__(self, center: tuple[float, float], ax: float, ay: float, samples: int = 2048):
        ang = np.linspace(0.0, 2 * np.pi, samples + 1)
        pts = np.stack([center[0] + ax * np.cos(ang), center[1] + ay * np.sin(ang)], axis=1)
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        self.points = pts
        self.cum = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.cum[-1])

    def at(self, s: float) -> tuple[np.ndarray, float]:
        """Point (2,) and tangent heading (radians) at arc length ``s`` (wraps around)."""
        s = s % self.length
        i = int(np.searchsorted(self.cum, s, side="right") - 1)
        i = min(max(i, 0), len(self.points) - 2)
        f = (s - self.cum[i]) / max(self.cum[i + 1] - self.cum[i], 1e-12)
        p = self.points[i] * (1 - f) + self.points[i + 1] * f
        d = self.points[i + 1] - self.points[i]
        return p, math.atan2(d[1], d[0])

    def closest(self, xy: tuple[float, float]) -> float:
        """Arc length of the path point nearest to ``xy``."""
        dist = np.linalg.norm(self.points - np.asarray(xy), axis=1)
        return float(self.cum[int(np.argmin(dist))])


# --------------------------------------------------------------------------- behaviour


@dataclass(frozen=True)
class Seat:
    """A chair seat a person can sit on: centre over the floor and facing direction."""

    x: float
    y: float
    facing: float


@dataclass(frozen=True)
class Segment:
    kind: str  # "walk", "goto", "pause", "sit", "seated", "still"
    t0: float
    t1: float
    s0: float = 0.0  # path arc length at t0
    direction: float = 1.0
    heading0: float = 0.0
    heading1: float = 0.0
    heading2: float = 0.0  # "sit": the heading to turn to after getting up
    seat: Seat | None = None
    x0: float = 0.0  # root at t0 ("goto": start; "sit": the spot in front of the seat)
    y0: float = 0.0
    x1: float = 0.0  # "goto": end
    y1: float = 0.0


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


@dataclass
class Behaviour:
    """What one person does over time. Build with :meth:`walking`, :meth:`seated` or :meth:`still`."""

    segments: list[Segment]
    path: LoopPath | None = None
    speed: float = 1.0
    idle: float = 1.0  # amplitude of fidgeting when not walking (0: frozen)
    stride: float = 1.3  # metres per gait cycle
    idle_phase: float = 0.0
    still_pose: BodyPose | None = None
    _t0s: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._t0s = np.array([seg.t0 for seg in self.segments])

    # ------------------------------------------------------------------ builders

    @classmethod
    def still(cls, pose: BodyPose) -> Behaviour:
        seg = Segment("still", -1e9, 1e9, heading0=pose.heading, x0=pose.x, y0=pose.y)
        return cls([seg], idle=0.0, still_pose=pose)

    @classmethod
    def seated(cls, seat: Seat, idle: float, rng: np.random.Generator) -> Behaviour:
        seg = Segment("seated", -1e9, 1e9, seat=seat, heading0=seat.facing, heading1=seat.facing)
        return cls([seg], idle=idle, idle_phase=float(rng.uniform(0, 100)))

    @classmethod
    def walking(
        cls,
        path: LoopPath,
        rng: np.random.Generator,
        duration: float,
        *,
        s_start: float,
        direction: float,
        speed: float,
        seat: Seat | None = None,
        sit_at: float | None = None,
    ) -> Behaviour:
        """Walk the loop with occasional pauses / turn-arounds.

        With a ``seat``: arrive at it at ``sit_at`` seconds (``s_start`` is then ignored: the
        start is planned backwards), sit for a few seconds, and again every
        :data:`SIT_EVERY` seconds.
        """
        segs: list[Segment] = []
        t, s, direc = -2.0, s_start, direction  # start before 0 so frame 0 is mid-stride
        next_sit = sit_at if seat is not None else None
        if seat is not None and sit_at is not None:
            stand = (seat.x + 0.45 * math.cos(seat.facing), seat.y + 0.45 * math.sin(seat.facing))
            s = path.closest(stand) - direc * speed * (sit_at - t)
        while t < duration + 2.0:
            if next_sit is not None and (t >= next_sit or not segs):
                # walk to the path point nearest the seat, step in front of it, turn, sit, rest,
                # get up, step back onto the path
                assert seat is not None
                stand = (
                    seat.x + 0.45 * math.cos(seat.facing),
                    seat.y + 0.45 * math.sin(seat.facing),
                )
                s_near = path.closest(stand)
                walk_t = ((s_near - s) * direc) % path.length / speed
                segs.append(Segment("walk", t, t + walk_t, s0=s, direction=direc))
                t += walk_t
                s = s_near
                p, _ = path.at(s)
                step = math.hypot(stand[0] - p[0], stand[1] - p[1])
                away = math.atan2(stand[1] - p[1], stand[0] - p[0])
                segs.append(Segment("goto", t, t + step / speed, x0=float(p[0]), y0=float(p[1]),
                                    x1=stand[0], y1=stand[1], heading0=away))  # fmt: skip
                t += step / speed
                rest = float(rng.uniform(1.5, 3.0))
                turns = (
                    abs(_wrap(seat.facing - away)) + abs(_wrap(away + math.pi - seat.facing))
                ) / TURN_RATE
                end = t + 2 * SIT_TIME + rest + turns
                segs.append(
                    Segment("sit", t, end, heading0=away, heading1=seat.facing,
                            heading2=away + math.pi, seat=seat, x0=stand[0], y0=stand[1])
                )  # fmt: skip
                t = end
                segs.append(Segment("goto", t, t + step / speed, x0=stand[0], y0=stand[1],
                                    x1=float(p[0]), y1=float(p[1]), heading0=away + math.pi))  # fmt: skip
                t += step / speed
                next_sit = t + SIT_EVERY
                continue
            walk_t = float(rng.uniform(2.5, 7.0))
            segs.append(Segment("walk", t, t + walk_t, s0=s, direction=direc))
            t += walk_t
            s += direc * speed * walk_t
            if rng.random() < 0.6:  # stop, look around, maybe turn back
                _, tangent = path.at(s)
                heading = tangent if direc > 0 else tangent + math.pi
                back = rng.random() < 0.5
                pause = float(rng.uniform(1.5, 3.5)) + (math.pi / TURN_RATE if back else 0.0)
                segs.append(
                    Segment("pause", t, t + pause, s0=s, heading0=heading,
                            heading1=heading + (math.pi if back else 0.0))
                )  # fmt: skip
                t += pause
                if back:
                    direc = -direc
        segs.append(Segment("walk", t, 1e9, s0=s, direction=direc))
        return cls(segs, path=path, speed=speed, idle=1.0, idle_phase=float(rng.uniform(0, 100)))

    # ------------------------------------------------------------------ evaluation

    def pose(self, t: float) -> BodyPose:
        """The body pose at time ``t`` (seconds from the sequence start)."""
        if self.still_pose is not None:
            return self.still_pose
        k = int(np.searchsorted(self._t0s, t, side="right") - 1)
        seg = self.segments[max(k, 0)]
        dt = t - seg.t0
        fid = self._fidget(t)
        if seg.kind == "walk":
            assert self.path is not None
            s = seg.s0 + seg.direction * self.speed * dt
            p, tangent = self.path.at(s)
            heading = tangent if seg.direction > 0 else tangent + math.pi
            phase = 2 * math.pi * (s * seg.direction) / self.stride
            # ease in / out of a walk so limbs do not snap
            g = min(1.0, dt / 0.4, (seg.t1 - t) / 0.4) if seg.t1 < 1e8 else min(1.0, dt / 0.4)
            return BodyPose(float(p[0]), float(p[1]), heading, phase, max(g, 0.0), 0.0, 0.05)
        if seg.kind == "pause":
            assert self.path is not None
            p, _ = self.path.at(seg.s0)
            turn = _wrap(seg.heading1 - seg.heading0)
            f = min(1.0, dt * TURN_RATE / max(abs(turn), 1e-6))
            heading = seg.heading0 + turn * f
            stepping = 0.25 if 0 < f < 1 else 0.0
            return BodyPose(float(p[0]), float(p[1]), heading, dt * 6, stepping, 0.0, *fid)
        if seg.kind == "seated":
            st = seg.seat
            assert st is not None
            return BodyPose(st.x, st.y, st.facing, 0.0, 0.0, 1.0, *fid)
        if seg.kind == "goto":
            f = dt / max(seg.t1 - seg.t0, 1e-6)
            x = seg.x0 + (seg.x1 - seg.x0) * f
            y = seg.y0 + (seg.y1 - seg.y0) * f
            dist = math.hypot(x - seg.x0, y - seg.y0)
            return BodyPose(x, y, seg.heading0, 2 * math.pi * dist / self.stride, 1.0, 0.0, 0.05)
        # "sit": turn to face away from the seat, sit down, rest, get up, turn to leave
        st = seg.seat
        assert st is not None
        turn_in = _wrap(seg.heading1 - seg.heading0)
        turn_out = _wrap(seg.heading2 - seg.heading1)
        in_t, out_t = abs(turn_in) / TURN_RATE, abs(turn_out) / TURN_RATE
        total = seg.t1 - seg.t0
        if dt < in_t:
            h = seg.heading0 + turn_in * dt / max(in_t, 1e-6)
            return BodyPose(seg.x0, seg.y0, h, dt * 6, 0.25, 0.0, 0.05)
        if dt > total - out_t:
            f = (dt - (total - out_t)) / max(out_t, 1e-6)
            h = seg.heading1 + turn_out * f
            return BodyPose(seg.x0, seg.y0, h, dt * 6, 0.25, 0.0, 0.05)
        turn_t = in_t
        inner_total = total - in_t - out_t
        inner = dt - turn_t
        if inner < SIT_TIME:
            f = _smooth(inner / SIT_TIME)
        elif inner > inner_total - SIT_TIME:
            f = _smooth((inner_total - inner) / SIT_TIME)
        else:
            f = 1.0
        x = seg.x0 + (st.x - seg.x0) * f
        y = seg.y0 + (st.y - seg.y0) * f
        lean = 0.45 * math.sin(math.pi * f) if f < 1 else fid[0]
        return BodyPose(x, y, st.facing, 0.0, 0.0, f, lean, *fid[1:])

    def _fidget(self, t: float) -> tuple[float, float, tuple[float, float]]:
        """Small idle motions: torso lean, head turn, arm gestures (zero when ``idle`` is 0)."""
        a, p = self.idle, self.idle_phase + t
        if a == 0:
            return 0.0, 0.0, (0.0, 0.0)
        lean = a * (0.06 * math.sin(0.7 * p) + 0.03 * math.sin(1.9 * p))
        head = a * (0.45 * math.sin(0.45 * p) + 0.15 * math.sin(1.3 * p))
        gesture_l = a * 0.5 * max(0.0, math.sin(0.55 * p + 1.0)) ** 2
        gesture_r = a * 0.6 * max(0.0, math.sin(0.8 * p + 2.5)) ** 3
        return lean, head, (gesture_l, gesture_r)


def _smooth(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3 - 2 * x)

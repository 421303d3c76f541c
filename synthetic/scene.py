"""Scene layouts: the office of the TUM-like sequences and random layouts for the VOC set.

World frame: metres, z up, floor at ``z = 0``. Furniture is static (built once); people are
posed per time step by their :class:`~.people.Behaviour`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uss_slam.core.classes import CLASS_NAMES

from .people import SEAT_HEIGHT, Behaviour, BodyPose, LoopPath, Outfit, Seat, body_prims
from .primitives import Prim, PrimArrays, box, cylinder, rot_z
from .renderer import Lighting, PointLight, Room
from .seeding import stream
from .textures import PEOPLE_SLOTS, material

BACKGROUND = CLASS_NAMES.index("background")
CHAIR = CLASS_NAMES.index("chair")
MONITOR = CLASS_NAMES.index("monitor")

ROOM_MATERIALS = tuple(
    material(n) for n in ("wall_a", "wall_b", "wall_c", "wall_d", "floor", "ceiling")
)


# --------------------------------------------------------------------------- furniture


def _local(cx: float, cy: float, heading: float):
    r = rot_z(heading)
    origin = np.array([cx, cy, 0.0])

    def to_world(p) -> np.ndarray:
        return origin + r @ np.asarray(p, np.float64)

    return to_world, r


def desk(cx, cy, heading, width=1.4, depth=0.75, height=0.74, tint=(1, 1, 1)) -> list[Prim]:
    """A desk: top and two side panels. Local x is the depth axis, ``heading`` its direction."""
    w, r = _local(cx, cy, heading)
    top, frame = material("desk"), material("desk_frame")
    prims = [box(w((0, 0, height - 0.02)), (depth, width, 0.04), BACKGROUND, top, r, tint)]
    for sy in (-1, 1):
        prims.append(
            box(w((0, sy * (width / 2 - 0.03), (height - 0.04) / 2)),
                (depth - 0.06, 0.04, height - 0.04), BACKGROUND, frame, r)
        )  # fmt: skip
    prims.append(  # modesty panel at the back
        box(w((depth / 2 - 0.05, 0, height * 0.55)), (0.02, width - 0.1, height * 0.5),
            BACKGROUND, frame, r)
    )  # fmt: skip
    return prims


def monitor(cx, cy, facing, base_z, width=0.56, height=0.34) -> list[Prim]:
    """A flat screen on a stand, screen facing ``facing`` (radians)."""
    w, r = _local(cx, cy, facing)
    body, screen = material("monitor_body"), material("monitor_screen")
    mid = base_z + 0.11 + height / 2
    return [
        box(w((0, 0, base_z + 0.008)), (0.2, 0.25, 0.016), MONITOR, body, r),
        box(w((-0.02, 0, base_z + 0.07)), (0.03, 0.06, 0.12), MONITOR, body, r),
        box(w((0.0, 0, mid)), (0.035, width, height), MONITOR, body, r),
        box(w((0.02, 0, mid)), (0.006, width - 0.03, height - 0.03), MONITOR, screen, r),
    ]


def chair(cx, cy, facing, office: bool = True, tint=(1, 1, 1)) -> list[Prim]:
    """A chair whose seated person faces ``facing``; the back is on the opposite side."""
    w, r = _local(cx, cy, facing)
    seat, frame = material("chair_seat"), material("chair_frame")
    st = SEAT_HEIGHT
    prims = [
        box(w((0, 0, st - 0.035)), (0.46, 0.46, 0.07), CHAIR, seat, r, tint),
        box(w((-0.22, 0, st + 0.28)), (0.06, 0.44, 0.46), CHAIR, seat, r, tint),
    ]
    if office:
        prims += [
            cylinder(w((0, 0, 0.05)), w((0, 0, st - 0.07)), 0.03, CHAIR, frame),
            cylinder(w((0, 0, 0.0)), w((0, 0, 0.05)), 0.3, CHAIR, frame),
            cylinder(w((-0.22, 0, st - 0.07)), w((-0.22, 0, st + 0.05)), 0.025, CHAIR, frame),
        ]
    else:
        for sx in (-0.2, 0.2):
            for sy in (-0.2, 0.2):
                prims.append(
                    cylinder(w((sx, sy, 0.0)), w((sx, sy, st - 0.07)), 0.022, CHAIR, frame)
                )
    return prims


def desk_clutter(
    rng: np.random.Generator, cx, cy, heading, width, depth, height=0.74
) -> list[Prim]:
    """Things on and under a desk (class background): a drawer pedestal at the front, a
    keyboard, stacks of books and boxes, a mug. Local x is the desk's depth axis."""
    w, r = _local(cx, cy, heading)
    clutter, frame = material("clutter"), material("cabinet")
    side = float(rng.choice([-1.0, 1.0]))
    ped_y = side * (width / 2 - 0.3)
    prims = [box(w((-depth / 2 + 0.25, ped_y, 0.3)), (0.45, 0.4, 0.6), BACKGROUND, frame, r)]
    prims.append(box(w((-depth / 2 + 0.18, 0.0, height + 0.012)), (0.16, 0.45, 0.024),
                     BACKGROUND, clutter, r))  # fmt: skip
    for _ in range(int(rng.integers(2, 5))):
        bw, bd, bh = rng.uniform(0.12, 0.32), rng.uniform(0.1, 0.25), rng.uniform(0.03, 0.12)
        y = float(rng.uniform(-width / 2 + 0.15, width / 2 - 0.15))
        x = float(rng.uniform(-depth / 2 + 0.12, depth / 2 - 0.15))
        turn = r @ rot_z(float(rng.uniform(-0.5, 0.5)))
        prims.append(box(w((x, y, height + bh / 2)), (bd, bw, bh), BACKGROUND, clutter, turn))
    mx, my = float(rng.uniform(-0.2, 0.1)), float(rng.uniform(-width / 2 + 0.1, width / 2 - 0.1))
    prims.append(
        cylinder(w((mx, my, height)), w((mx, my, height + 0.1)), 0.04, BACKGROUND, clutter)
    )
    return prims


def cabinet(cx, cy, heading, width, depth, height) -> list[Prim]:
    w, r = _local(cx, cy, heading)
    return [box(w((0, 0, height / 2)), (depth, width, height), BACKGROUND, material("cabinet"), r)]


# --------------------------------------------------------------------------- scenes


@dataclass
class Scene:
    """A room with static furniture and people, able to produce its primitives at any time."""

    room: Room
    static: list[Prim]
    people: list[tuple[Outfit, Behaviour]]
    lights: tuple[tuple[float, float, float], ...]
    eye: np.ndarray  # a good camera position (the preset motions move around it)
    target: np.ndarray  # where that camera looks

    def __post_init__(self) -> None:
        self._static = PrimArrays.stack(self.static)

    def prims_at(self, t: float) -> PrimArrays:
        """All primitives at ``t`` seconds: furniture first, then the people."""
        moving: list[Prim] = []
        for outfit, behaviour in self.people:
            moving += body_prims(behaviour.pose(t), outfit)
        return self._static.concat(PrimArrays.stack(moving)) if moving else self._static

    def lighting(self, style: str) -> Lighting:
        """``source``: even and bright; ``target``: a few falling-off ceiling lights, warmer."""
        if style == "source":
            return Lighting(
                ambient=0.62,
                hemi=0.18,
                lights=(PointLight(self.lights[0], 0.3, 4.0),),
            )
        return Lighting(
            ambient=0.22,
            hemi=0.12,
            lights=tuple(PointLight(p, 1.05, 2.2) for p in self.lights),
            color=(1.0, 0.93, 0.82),
        )


def _outfit(rng: np.random.Generator, slot: int) -> Outfit:
    return Outfit(
        slot=slot % PEOPLE_SLOTS,
        height=float(rng.uniform(1.62, 1.9)),
        shirt_tint=tuple(float(c) for c in rng.uniform(0.8, 1.15, 3)),
        trousers_tint=tuple(float(c) for c in rng.uniform(0.8, 1.15, 3)),
    )


EYE_X = -1.6
"""World x of the camera's rest position in the office (it looks along +x)."""
WALK_LANES: dict[str, tuple[tuple[float, float, float, float, float], ...]] = {
    # (distance ahead of the camera's rest position along x, lane centre y, half length of the
    #  lane across the view, walking speed m/s, initial direction) for the two walking people
    "xyz": ((0.7, 0.0, 0.8, 0.15, 1.0), (1.15, 0.15, 1.0, 0.2, -1.0)),
    # the half-sphere camera moves ~0.5 m forward and sideways: lanes a little further ahead
    # and shorter, between the camera and the point it looks at, so the people stay in view
    "halfsphere": ((1.2, 0.0, 0.5, 0.15, 1.0), (1.5, 0.15, 0.5, 0.15, -1.0)),
}
"""Where the two people of the walking presets walk, per camera motion (``xyz`` the default)."""


def office_scene(seed: int, people: str, duration: float, motion: str = "xyz") -> Scene:
    """The office of the TUM-like sequences (same furniture for every preset of a seed).

    Two desks face the camera with monitors and chairs behind them (where seated people sit),
    shelves against the walls, a free chair beside the desks. ``people``: ``"walking"`` two people
    walk slowly back and forth across the view 0.6-1.6 m in front of the camera (lanes from
    :data:`WALK_LANES` by the camera ``motion``), pausing and turning now and then;
    ``"sitting"`` two seated people who move a little, ``"frozen"`` the same two never moving.
    """
    rng = stream(seed, "office")
    jit = lambda s: float(rng.uniform(-s, s))  # noqa: E731
    sx, sy, sz = 5.0 + jit(0.2), 6.0 + jit(0.3), 3.0 + jit(0.1)
    room = Room((-sx / 2, -sy / 2, 0.0), (sx / 2, sy / 2, sz), ROOM_MATERIALS)
    desk_x = 0.9 + jit(0.1)
    static: list[Prim] = []
    static += desk(desk_x, -0.72, 0.0, width=1.44)
    static += desk(desk_x, 0.72, 0.0, width=1.44)
    crng = stream(seed, "office/clutter")
    for cy in (-0.72, 0.72):
        static += desk_clutter(crng, desk_x, cy, 0.0, 1.44, 0.75)
    # monitors between and beside the seats, so that seated people stay in view
    monitors_y = [-1.12 + jit(0.05), 0.02 + jit(0.05), 1.12 + jit(0.05)]
    for my in monitors_y:
        static += monitor(desk_x + 0.1, my, math.pi + jit(0.25), 0.74)
    seats = [
        Seat(desk_x + 0.85, -0.65 + jit(0.1), math.pi + jit(0.2)),
        Seat(desk_x + 0.85, 0.7 + jit(0.1), math.pi + jit(0.2)),
    ]
    for st in seats:
        static += chair(st.x, st.y, st.facing, office=True)
    side_seat = Seat(desk_x + 0.15, 1.75, math.pi + jit(0.3))
    static += chair(side_seat.x, side_seat.y, side_seat.facing, office=False)
    static += chair(-0.2 + jit(0.1), -2.4, math.pi / 2 + jit(0.3), office=bool(rng.random() < 0.5))
    hx, hy = room.hi[0], room.hi[1]
    static += cabinet(hx - 0.2, -hy + 1.3, math.pi, 1.4, 0.4, 1.9)  # shelf on the far wall
    static += cabinet(hx - 0.25, hy - 1.0, math.pi, 1.0, 0.5, 1.1)
    static += cabinet(-0.3 + jit(0.2), hy - 0.25, -math.pi / 2, 1.6, 0.45, 0.9)
    static += cabinet(-1.1, -hy + 0.25, math.pi / 2, 0.9, 0.45, 1.5)
    static += desk(-0.3 + jit(0.2), hy - 0.8, -math.pi / 2, width=1.2, depth=0.6)
    static += monitor(-0.3, hy - 0.7, -math.pi / 2 + math.pi, 0.74)

    prng = stream(seed, "office/people")
    persons: list[tuple[Outfit, Behaviour]] = []
    if people == "walking":
        # As in TUM's walking sequences, two people walk slowly back and forth across the view
        # close to the camera (about 0.7 and 1.15 m ahead of its rest position), filling much of
        # the image with textured clothing: slow enough (a few pixels per frame) that an
        # unfiltered tracker takes their keypoints into its pose. Lanes per camera motion.
        for _ in range(5):  # the draws of earlier layouts, so the camera's rest position is kept
            jit(0.05)
        lanes = WALK_LANES.get(motion, WALK_LANES["xyz"])
        for k, (dx, cy, half, speed, direction) in enumerate(lanes):
            path = LoopPath((EYE_X + dx, cy), 0.1, half)
            behaviour = Behaviour.walking(
                path,
                stream(seed, "office/walk", k),
                duration,
                s_start=path.length * float(prng.uniform(0.0, 1.0)),
                direction=direction,
                speed=speed,
            )
            persons.append((_outfit(prng, k), behaviour))
    elif people in ("sitting", "frozen"):
        for k, st in enumerate(seats):
            outfit = _outfit(prng, k)
            if people == "sitting":
                behaviour = Behaviour.seated(st, 1.0, stream(seed, "office/sit", k))
            else:
                behaviour = Behaviour.still(BodyPose(st.x, st.y, st.facing, sit=1.0))
            persons.append((outfit, behaviour))
    elif people != "none":
        raise ValueError(f"unknown people mode {people!r}")

    lights = ((0.0, -1.5, sz - 0.2), (0.8, 1.5, sz - 0.2), (-1.5, 0.0, sz - 0.2))
    eye = np.array([EYE_X, 0.0 + jit(0.1), 1.35 + jit(0.05)])
    target = np.array([desk_x + 0.2, 0.0, 0.9])
    return Scene(room, static, persons, lights, eye, target)


def random_scene(seed: int, index: int) -> Scene:
    """A random room with random furniture and 1-3 people in random poses (for the VOC set)."""
    rng = stream(seed, "voc/scene", index)
    sx, sy, sz = rng.uniform(4.5, 7.0), rng.uniform(4.0, 6.5), rng.uniform(2.6, 3.3)
    room = Room((-sx / 2, -sy / 2, 0.0), (sx / 2, sy / 2, sz), ROOM_MATERIALS)
    occupied: list[tuple[float, float, float]] = []  # (x, y, radius) footprints

    def place(radius: float, margin: float = 0.3) -> tuple[float, float] | None:
        for _ in range(40):
            x = rng.uniform(-sx / 2 + radius + margin, sx / 2 - radius - margin)
            y = rng.uniform(-sy / 2 + radius + margin, sy / 2 - radius - margin)
            if all((x - a) ** 2 + (y - b) ** 2 > (radius + r) ** 2 for a, b, r in occupied):
                occupied.append((x, y, radius))
                return float(x), float(y)
        return None

    static: list[Prim] = []
    seats: list[Seat] = []
    for _ in range(int(rng.integers(1, 4))):
        spot = place(0.9)
        if spot is None:
            continue
        heading = float(rng.uniform(-math.pi, math.pi))
        width = float(rng.uniform(1.0, 1.6))
        tint = tuple(float(c) for c in rng.uniform(0.75, 1.2, 3))
        depth = float(rng.uniform(0.6, 0.8))
        static += desk(*spot, heading, width=width, depth=depth, tint=tint)
        static += desk_clutter(rng, *spot, heading, width, depth)
        d = rot_z(heading)
        for _ in range(int(rng.integers(0, 3))):
            off = d @ np.array([0.1, rng.uniform(-width / 2 + 0.3, width / 2 - 0.3), 0.0])
            static += monitor(spot[0] + off[0], spot[1] + off[1], heading + math.pi + rng.normal(0, 0.3), 0.74,
                              width=float(rng.uniform(0.4, 0.65)), height=float(rng.uniform(0.26, 0.4)))  # fmt: skip
        # a chair behind the desk, facing it
        back = d @ np.array([0.75, rng.uniform(-0.3, 0.3), 0.0])
        seats.append(
            Seat(spot[0] + back[0], spot[1] + back[1], heading + math.pi + rng.normal(0, 0.4))
        )
    for st in seats:
        static += chair(st.x, st.y, st.facing, office=bool(rng.random() < 0.6),
                        tint=tuple(float(c) for c in rng.uniform(0.7, 1.25, 3)))  # fmt: skip
    for _ in range(int(rng.integers(0, 4))):
        spot = place(0.35)
        if spot is None:
            continue
        facing = float(rng.uniform(-math.pi, math.pi))
        static += chair(*spot, facing, office=bool(rng.random() < 0.5),
                        tint=tuple(float(c) for c in rng.uniform(0.7, 1.25, 3)))  # fmt: skip
        seats.append(Seat(spot[0], spot[1], facing))
    for _ in range(int(rng.integers(1, 4))):
        wall = int(rng.integers(0, 4))
        width, depth, height = rng.uniform(0.6, 1.8), rng.uniform(0.3, 0.55), rng.uniform(0.8, 2.0)
        along = rng.uniform(-1.0, 1.0)
        if wall < 2:
            x = (sx / 2 - depth / 2 - 0.02) * (1 if wall else -1)
            y = along * (sy / 2 - width / 2 - 0.1)
            heading = math.pi if wall else 0.0
        else:
            y = (sy / 2 - depth / 2 - 0.02) * (1 if wall == 3 else -1)
            x = along * (sx / 2 - width / 2 - 0.1)
            heading = -math.pi / 2 if wall == 3 else math.pi / 2
        static += cabinet(x, y, heading, width, depth, height)

    persons: list[tuple[Outfit, Behaviour]] = []
    free_seats = list(seats)
    for _ in range(int(rng.integers(1, 4))):
        outfit = _outfit(rng, int(rng.integers(0, 64)))
        if free_seats and rng.random() < 0.35:
            st = free_seats.pop(int(rng.integers(0, len(free_seats))))
            lean, head = rng.uniform(-0.1, 0.3), rng.uniform(-0.6, 0.6)
            arms = tuple(float(a) for a in rng.uniform(0, 0.8, 2) * (rng.random(2) < 0.4))
            pose = BodyPose(st.x, st.y, st.facing, sit=1.0, lean=lean, head_yaw=head, arms=arms)
        else:
            spot = place(0.3)
            if spot is None:
                continue
            walking = rng.random() < 0.6
            pose = BodyPose(
                *spot,
                heading=float(rng.uniform(-math.pi, math.pi)),
                phase=float(rng.uniform(0, 2 * math.pi)),
                gait=float(rng.uniform(0.6, 1.0)) if walking else 0.0,
                lean=float(rng.uniform(-0.05, 0.15)),
                head_yaw=float(rng.uniform(-0.6, 0.6)),
                arms=tuple(float(a) for a in rng.uniform(0, 0.9, 2) * (rng.random(2) < 0.3)),
            )
        persons.append((outfit, Behaviour.still(pose)))

    lights = tuple(
        (float(rng.uniform(-sx / 3, sx / 3)), float(rng.uniform(-sy / 3, sy / 3)), float(sz - 0.2))
        for _ in range(3)
    )
    return Scene(room, static, persons, lights, np.zeros(3), np.zeros(3))

"""Concealed-physics scenes for the third-party test set: what is on the table, how the robot
pushes, and the effect pegs's model is not told about (the hidden truth), drawn at random from a
seed. Owns the draws only; never simulates (simulate.py) or writes (write.py).

Units SI, world z up; the Panda's base is at the origin and reaches the table around x = 0.5 m.
Every parameter of a scene comes from `random.Random(seed)`, so a seed is a scene.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field, replace

# The families a scene can hide, and the two controls.
KINDS = ["control_pushed", "control_still", "tilt", "drag", "patch", "weight", "tether", "heavy", "restitution"]

# Issue 25's set of model errors: friction several times too high (`slippery`: the table is) and
# too low (`sticky`), an unmodelled spring (`tether`), a mass five times wrong in a collision
# (`heavy5`), an unmodelled hand pushing the object (`hand`), and the model right (the controls).
MODEL_ERRORS = ["slippery", "sticky", "tether", "heavy5", "hand", "control_pushed", "control_still"]

# Recording shapes: one push then rest, a push that lasts the whole recording, several pushes.
SHAPES = ["push_then_rest", "long_push", "several_pushes"]

COLOURS = [(0.95, 0.45, 0.1), (0.2, 0.4, 0.9), (0.2, 0.75, 0.3)]


@dataclass
class Part:
    """A box of the object in its body frame: centre (m) and half sizes (m)."""

    centre: tuple[float, float, float]
    half: tuple[float, float, float]


@dataclass
class Obj:
    name: str
    label: int  # instance-mask value
    shape: str  # box | cylinder | bar | tblock
    mass: float  # kg, what the user's configuration says
    x: float
    y: float
    yaw: float
    z: float = 0.0  # height of the body frame above its resting height (a drop)
    colour: tuple[float, float, float] = (0.95, 0.45, 0.1)
    # cylinder: (radius, half height); others: parts
    radius: float = 0.0
    half_height: float = 0.0
    parts: list[Part] = field(default_factory=list)
    true_mass: float = 0.0  # kg, what the engine simulates (differs in `heavy`)
    com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # body frame, m (`weight`)

    def footprint(self) -> float:
        """Radius of the object's footprint on the table, m."""
        if self.shape == "cylinder":
            return self.radius
        return max(math.hypot(abs(p.centre[0]) + p.half[0], abs(p.centre[1]) + p.half[1]) for p in self.parts)

    def extent(self, d: tuple[float, float]) -> float:
        """How far the object reaches from its body origin in world direction `d` (unit, on the table)."""
        if self.shape == "cylinder":
            return self.radius
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        bx, by = c * d[0] + s * d[1], -s * d[0] + c * d[1]
        return max(p.centre[0] * bx + p.centre[1] * by + p.half[0] * abs(bx) + p.half[1] * abs(by) for p in self.parts)

    def chord(self, point: tuple[float, float], d: tuple[float, float], margin: float = 0.0) -> tuple[float, float] | None:
        """Where the line through `point` along unit `d` runs inside the object's outline shrunk
        by `margin` (on the table, object at rest where it stands): the first and last distance
        along `d` from `point`, or None when it misses."""
        if self.shape == "cylinder":
            px, py = point[0] - self.x, point[1] - self.y
            lateral, along = px * -d[1] + py * d[0], px * d[0] + py * d[1]
            r = self.radius - margin
            if abs(lateral) >= r:
                return None
            half = math.sqrt(r * r - lateral * lateral)
            return (-along - half, -along + half)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        spans = []
        for p in self.parts:
            cx = self.x + c * p.centre[0] - s * p.centre[1]
            cy = self.y + s * p.centre[0] + c * p.centre[1]
            # The line in the part's frame, clipped against each slab of the shrunk rectangle.
            q = ((point[0] - cx) * c + (point[1] - cy) * s, -(point[0] - cx) * s + (point[1] - cy) * c)
            e = (d[0] * c + d[1] * s, -d[0] * s + d[1] * c)
            lo, hi = -math.inf, math.inf
            for k in range(2):
                h = p.half[k] - margin
                if h <= 0:
                    lo, hi = 1.0, 0.0
                elif abs(e[k]) < 1e-9:
                    if abs(q[k]) > h:
                        lo, hi = 1.0, 0.0
                else:
                    a, b = (-h - q[k]) / e[k], (h - q[k]) / e[k]
                    lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
            if lo < hi:
                spans.append((lo, hi))
        if not spans:
            return None
        return (min(a for a, _ in spans), max(b for _, b in spans))

    def crossed_by(self, point: tuple[float, float], d: tuple[float, float], margin: float) -> bool:
        """Whether the line through `point` along `d` crosses the object's outline shrunk by
        `margin` (on the table, object at rest where it stands)."""
        return self.chord(point, d, margin) is not None

    def contains(self, point: tuple[float, float], grown: float = 0.0) -> bool:
        """Whether `point` on the table lies inside the object's outline grown by `grown` (m)."""
        span = self.chord(point, (1.0, 0.0), -grown)
        return span is not None and span[0] <= 0.0 <= span[1]

    def overlaps(self, other: "Obj", clearance: float) -> bool:
        """Whether `other`'s footprint comes within `clearance` (m) of this one's, tested on a
        1 mm grid over `other`'s footprint."""
        step, reach = 0.001, other.footprint()
        n = int(reach / step) + 1
        points = ((other.x + i * step, other.y + j * step) for i in range(-n, n + 1) for j in range(-n, n + 1))
        return any(other.contains(q) and self.contains(q, clearance) for q in points)

    def half_height_z(self) -> float:
        if self.shape == "cylinder":
            return self.half_height
        return max(p.half[2] for p in self.parts)


@dataclass
class Push:
    """The pusher tip moves from `start` to `end` (x, y on the table) between t0 and t1."""

    t0: float
    t1: float
    start: tuple[float, float]
    end: tuple[float, float]
    # The object's place and turn (x, y, yaw) the push is aimed at; a later push follows the
    # object from there, from the end of the push before until it starts (`simulate.follow`).
    aim: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        # Where it was first aimed (`aim` moves with the object).
        self.planned = self.aim


@dataclass
class Scene:
    kind: str
    seed: int
    shape: str
    duration: float
    friction: float  # table and objects, what the user's configuration says
    objects: list[Obj]
    pushes: list[Push]
    # The hidden truth: family, parameter and where (the judge reads this, pegs never does).
    truth: dict
    # Engine-side settings of the effect.
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    drag: float = 0.0  # N s/m on the first object
    patch: dict | None = None  # {"edge_point": [x, y], "normal": [x, y], "friction": mu}: beyond the edge
    spring: dict | None = None  # {"anchor": [x, y, z], "point": body-frame [x, y, z], "stiffness": N/m, "rest_length": m}
    restitution: float | None = None  # MuJoCo contact damping ratio of the dropped object
    engine_friction: float | None = None  # the engine's friction where it differs from `friction`
    hand: list[Push] = field(default_factory=list)  # an unmodelled kinematic body's pushes
    # Where the objects bear on the table: MuJoCo's own box-plane contact at the four bottom
    # corners ("corners"), or spread over a grid of points under the bottom face ("spread", as
    # pegs's particles bear). It decides how far a push turns an object (tests/mujoco/support.py).
    support: str = "corners"
    # Whether a later push (of the robot or the hand) follows its object from where it was aimed,
    # from the end of the push before until it starts (`simulate.follow`). Without, every push is
    # planned from where the objects stand at the start, and one can bring the rod down into an
    # object an earlier push moved: MuJoCo's kinematic rod then passes into it (soft contacts)
    # while the images show it unmoved, as a robot model that is off would put its rod there.
    follow: bool = True
    # The robot's and the objects' contacts at `simulate.STIFF_CONTACT` instead of MuJoCo's soft
    # default, with which a push needs the rod millimetres inside its object.
    stiff_contacts: bool = False


def make_object(rng: random.Random, shape: str, name: str, label: int, x: float, y: float) -> Obj:
    """An object of `shape` with random size and mass, resting at (x, y) with a random yaw."""
    colour = COLOURS[(label - 1) % len(COLOURS)]
    yaw = rng.uniform(-math.pi, math.pi)
    mass = round(rng.uniform(0.15, 0.4), 3)
    o = Obj(name=name, label=label, shape=shape, mass=mass, x=x, y=y, yaw=yaw, colour=colour, true_mass=mass)
    h = rng.uniform(0.015, 0.025)
    if shape == "cylinder":
        o.radius, o.half_height = rng.uniform(0.03, 0.045), h
    elif shape == "box":
        o.parts = [Part((0, 0, 0), (rng.uniform(0.03, 0.05), rng.uniform(0.025, 0.04), h))]
    elif shape == "bar":
        o.parts = [Part((0, 0, 0), (rng.uniform(0.09, 0.12), rng.uniform(0.015, 0.02), h))]
    elif shape == "tblock":
        # The top bar along x at +y, the stem below it along y.
        w, t = rng.uniform(0.08, 0.1), rng.uniform(0.022, 0.028)
        stem = rng.uniform(0.06, 0.075)
        o.parts = [Part((0, t, 0), (w, t, h)), Part((0, -stem, 0), (t, stem, h))]
    else:
        raise ValueError(f"unknown shape {shape}")
    return o


# Kinds whose effect shows while an object slides free: their short pushes are strikes, fast
# enough that the object slides on after the rod stops. (A long, slow push hides them: then the
# honest verdict is "not enough evidence".)
STRIKES = {"drag", "tilt", "patch", "heavy", "slippery", "sticky", "heavy5"}


# Least gap (m) between the two objects of a collision scene as drawn.
SECOND_CLEARANCE = 0.001


# The pusher's radius (urdf/panda_pusher.urdf's rod 15 mm, the hand 18 mm) with room to spare.
PUSHER_CLEARANCE = 0.02


def clean_strike(target: Obj, line: tuple[float, float], d: tuple[float, float]) -> bool:
    """Whether a pusher on the line through `line` along `d` first touches `target` where the line
    itself meets it (within 2 mm), not with its side on another part of it."""
    chord = target.chord(line, d)
    grown = target.chord(line, d, -PUSHER_CLEARANCE)
    return chord is not None and grown is not None and grown[0] >= chord[0] - PUSHER_CLEARANCE - 0.002


def plan_pushes(rng: random.Random, shape: str, target: Obj, duration: float, strike: bool,
                from_start: bool = False) -> list[Push]:
    """Pushes across `target` from random sides, shaped as `shape` within `duration`; short pushes
    at 8-14 cm/s, or 30-45 cm/s when they `strike`. Each push is laid out against the object
    where the pushes before it are meant to leave it; `from_start` lays every push out against
    the object where it stands at the start and starts the rod 3 cm behind the object's furthest
    extent rather than where the rod's line meets it (as recorded until the follow change)."""
    speeds = (0.3, 0.45) if strike else (0.08, 0.14)

    def push(t0: float, t1: float, centre: tuple[float, float], length: float) -> Push:
        aim = (centre[0], centre[1], target.yaw)
        at = target if from_start else replace(target, x=centre[0], y=centre[1])
        # Square on to one of the object's faces (within 15 degrees; a glancing push slides off),
        # and not straight at the robot's base, so the arm does not fold over.
        if target.shape == "cylinder":
            heading = rng.uniform(-0.6, 0.6) + rng.choice([0.0, math.pi / 2, -math.pi / 2])
        else:
            faces = [target.yaw + k * math.pi / 2 for k in range(4)]
            heading = rng.choice([a for a in faces if math.cos(a) > -0.5]) + rng.uniform(-0.26, 0.26)
        d = (math.cos(heading), math.sin(heading))
        # Off the centre line by part of the object's half width, so the object turns one way
        # (a push through the centre of mass is the unstable case: any engine may turn it
        # either way).
        side = (-d[1], d[0])
        width = min(target.extent(side), target.extent((-side[0], -side[1])))
        for _ in range(50):
            lateral = rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 0.6) * width
            line = (centre[0] + side[0] * lateral, centre[1] + side[1] * lateral)
            # The rod must strike the object squarely, a centimetre inside its outline, on the
            # face its line meets first: not brushing past another part of it on the way (beside
            # a T-block's stem towards its top bar), nor coming down onto one.
            if at.crossed_by(line, d, 0.01) and (from_start or clean_strike(at, line, d)):
                break
        else:
            line = centre
        centre = line
        # The rod starts 3 cm before it meets the object and travels `length` beyond that.
        chord = at.chord(line, d)
        if from_start or chord is None:
            back = target.extent((-d[0], -d[1])) + 0.03
        else:
            back = 0.03 - chord[0]
        start = (centre[0] - d[0] * back, centre[1] - d[1] * back)
        travel = 0.03 + length
        return Push(t0, t1, start, (start[0] + d[0] * travel, start[1] + d[1] * travel), aim)

    centre = (target.x, target.y)
    if shape == "push_then_rest":
        length = rng.uniform(0.06, 0.1)
        t0 = rng.uniform(0.3, 0.6)
        return [push(t0, t0 + length / rng.uniform(*speeds), centre, length)]
    if shape == "long_push":
        length = rng.uniform(0.1, 0.14)
        return [push(0.3, duration - 0.2, centre, length)]
    pushes, t = [], 0.3
    for _ in range(rng.choice([2, 3])):
        length = rng.uniform(0.04, 0.07)
        p = push(t, t + length / rng.uniform(*speeds), centre, length)
        pushes.append(p)
        # The next push is aimed where this one leaves the object (roughly) after a pause to
        # rest; the recording moves it to where the object is then (`simulate.follow`).
        dx, dy = p.end[0] - p.start[0], p.end[1] - p.start[1]
        n = math.hypot(dx, dy)
        centre = (centre[0] + dx / n * (length - 0.005), centre[1] + dy / n * (length - 0.005))
        t = p.t1 + rng.uniform(0.8, 1.2)
    return pushes


def draw(kind: str, seed: int, shape: str | None = None, from_start: bool = False) -> Scene:
    """The scene of `kind` for `seed` (recording shape drawn too unless given; `from_start`: the
    pushes laid out as recorded until the follow change, see `plan_pushes`)."""
    if kind not in KINDS + MODEL_ERRORS:
        raise ValueError(f"unknown kind {kind} (one of {', '.join(KINDS + MODEL_ERRORS[:-2])})")
    rng = random.Random(f"{kind}/{seed}")
    shape = shape or rng.choice(SHAPES)
    # A slippery table where the effect shows in sliding, so that an object slides a few cm.
    friction = round(rng.uniform(0.12, 0.2) if kind in ("drag", "tilt", "sticky") else rng.uniform(0.35, 0.6), 3)
    x, y = rng.uniform(0.47, 0.55), rng.uniform(-0.08, 0.08)
    obj_shape = rng.choice(["box", "cylinder", "bar", "tblock"])
    first = make_object(rng, obj_shape, "obj1", 1, x, y)
    objects = [first]
    duration = 4.0 if shape != "several_pushes" else 5.5
    pushes = plan_pushes(rng, shape, first, duration, kind in STRIKES, from_start)
    truth: dict = {"family": "none", "object": first.name}
    s = Scene(kind, seed, shape, duration, friction, objects, pushes, truth, follow=not from_start)
    if kind == "control_still":
        s.shape, s.pushes, s.duration = "still", [], 3.0
    elif kind == "tilt":
        angle = math.radians(rng.uniform(1.5, 3.0))
        azimuth = rng.uniform(-math.pi, math.pi)
        g = 9.81
        s.gravity = (g * math.sin(angle) * math.cos(azimuth), g * math.sin(angle) * math.sin(azimuth), -g * math.cos(angle))
        force = first.true_mass * g * math.sin(angle)
        s.truth = {"family": "constant_force", "object": first.name, "parameter": force, "unit": "N",
                   "direction": [math.cos(azimuth), math.sin(azimuth), 0.0], "tilt_deg": math.degrees(angle)}
    elif kind == "drag":
        s.drag = round(rng.uniform(0.6, 1.6), 3)
        s.truth = {"family": "viscous_drag", "object": first.name, "parameter": s.drag, "unit": "N s/m"}
    elif kind == "patch":
        # A slippery or sticky band across the push's path, starting part way along it.
        p = s.pushes[0]
        d = (p.end[0] - p.start[0], p.end[1] - p.start[1])
        mid = (p.start[0] + 0.6 * d[0], p.start[1] + 0.6 * d[1])
        mu = round(rng.choice([rng.uniform(0.1, 0.2), rng.uniform(0.9, 1.2)]), 3)
        n = math.hypot(*d)
        # The table beyond a straight edge across the path (through `mid`, facing along the push).
        s.patch = {"edge_point": list(mid), "normal": [d[0] / n, d[1] / n], "friction": mu}
        s.truth = {"family": "friction_patch", "object": first.name, "parameter": mu, "unit": "",
                   "edge_point": list(mid), "normal": [d[0] / n, d[1] / n]}
    elif kind == "weight":
        # A hidden weight: the centre of mass moved along the object's longest extent.
        if first.shape == "cylinder":
            reach = 0.6 * first.radius
        else:
            reach = 0.6 * max(abs(p.centre[0]) + p.half[0] for p in first.parts)
        sign = rng.choice([-1.0, 1.0])
        first.com_offset = (sign * rng.uniform(0.5, 1.0) * reach, 0.0, 0.0)
        s.truth = {"family": "center_of_mass_offset", "object": first.name,
                   "parameter": abs(first.com_offset[0]), "unit": "m", "offset_body": list(first.com_offset)}
    elif kind == "tether":
        # A cord from the object's centre to an anchor on the table, slack at the start.
        p = s.pushes[0]
        d = (p.end[0] - p.start[0], p.end[1] - p.start[1])
        n = math.hypot(*d)
        anchor = [x - d[0] / n * 0.12, y - d[1] / n * 0.12, 0.0]
        # Strong enough to beat friction: the object snaps back when the rod lets go.
        k = round(rng.uniform(15.0, 40.0), 3)
        s.spring = {"anchor": anchor, "point": [0.0, 0.0, 0.0], "stiffness": k, "rest_length": 0.12}
        s.truth = {"family": "spring", "object": first.name, "parameter": k, "unit": "N/m", "anchor": anchor}
    elif kind == "slippery":
        # The table is several times more slippery than configured: the object slides on.
        s.engine_friction = round(friction / rng.uniform(3.0, 5.0), 3)
        s.truth = {"family": "friction", "object": first.name, "parameter": s.engine_friction, "unit": "",
                   "configured": friction}
    elif kind == "sticky":
        # The table is several times less slippery than configured: the object stops short.
        s.engine_friction = round(friction * rng.uniform(3.0, 5.0), 3)
        s.truth = {"family": "friction", "object": first.name, "parameter": s.engine_friction, "unit": "",
                   "configured": friction}
    elif kind == "hand":
        # The robot stays parked; a hand the model does not have pushes the object.
        s.hand, s.pushes = s.pushes, []
        s.truth = {"family": "external_push", "object": first.name, "parameter": None, "unit": ""}
    elif kind in ("heavy", "heavy5"):
        # A second object in the first one's path, heavier than the configuration says.
        p = s.pushes[0]
        d = (p.end[0] - p.start[0], p.end[1] - p.start[1])
        n = math.hypot(*d)
        gap = first.footprint() + 0.045
        second = make_object(rng, rng.choice(["box", "cylinder"]), "obj2", 2, x + d[0] / n * gap, y + d[1] / n * gap)
        # Never into the first: objects that start interpenetrating are thrown apart at the
        # first step (heavy5_4500's box, 9 mm in 0.1 s), which no real scene does. Moved on
        # along the push until clear; scenes drawn clear stay as they were.
        while first.overlaps(second, SECOND_CLEARANCE):
            gap += 0.001
            second.x, second.y = x + d[0] / n * gap, y + d[1] / n * gap
        second.mass = first.mass
        ratio = round(rng.uniform(2.0, 4.0), 3) if kind == "heavy" else rng.choice([5.0, 0.2])
        second.true_mass = second.mass * ratio
        objects.append(second)
        # Long enough to carry the first object into the second.
        if s.shape == "push_then_rest":
            p.end = (p.end[0] + d[0] / n * 0.05, p.end[1] + d[1] / n * 0.05)
            p.t1 += 0.4
        s.truth = {"family": "mass_error", "object": second.name, "parameter": ratio, "unit": "",
                   "ratio_to": first.name}
    elif kind == "restitution":
        # Dropped from a height; the robot stays parked.
        first.z = round(rng.uniform(0.08, 0.15), 3)
        s.shape, s.pushes, s.duration = "drop", [], 2.5
        # MuJoCo's contact damping ratio; the coefficient it gives is measured from the bounce.
        s.restitution = rng.uniform(0.08, 0.2)
        s.truth = {"family": "restitution", "object": first.name, "parameter": None, "unit": ""}
    return s

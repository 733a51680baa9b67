"""A scene (scenes.py) simulated and rendered by MuJoCo: the Panda from pegs's URDF as MuJoCo
reads it, driven kinematically through MuJoCo's own inverse kinematics along the pushing plan;
the objects as free bodies with the scene's hidden effect applied by the engine; three cameras
rendering colour, depth and instance labels offscreen (EGL). Owns the engine side only; never
writes files (write.py).

Nothing here uses pegs's physics, kinematics or renderer: that is the point of the test set.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, replace

import mujoco
import numpy as np

from scenes import Obj, Scene

FRAME_RATE = 30.0
SUBSTEPS = 20  # engine steps per frame (600 Hz)
JOINT_RATE_DIVIDER = 6  # joint states at 100 Hz
TIP = (0.0, 0.0, -0.14)  # the rod's tip in the panda_pusher link frame
TIP_HEIGHT = 0.02  # above the table while pushing
ROD_RADIUS = 0.015  # the pusher rod's (urdf/panda_pusher.urdf)
PARKED = (0.3, -0.35, 0.25)  # where the tip waits in a scene without pushes
# MuJoCo's contact time constant and damping ratio (its `solref`) for the robot and the objects
# where a scene asks for stiff contacts (`Scene.stiff_contacts`): three engine steps. MuJoCo's
# default (0.02 s) is soft: a push needs the rod a few millimetres inside its object to move it, so
# a pushed object lags the rod by that much and rests so once the rod stops (heavy5_3400: 6.5 mm
# deep, over 3 mm for 72 frames), where a rigid one would rest against it.
STIFF_CONTACT = (0.005, 1.0)
HOME = [0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785]


@dataclass
class CameraModel:
    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    # The optical frame (REP-105: z forward, y down) in the world: rotation matrix and position.
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class Frame:
    t: float
    rgb: list[np.ndarray]  # per camera, HxWx3 uint8
    depth: list[np.ndarray]  # per camera, HxW float32 metres (0: nothing)
    labels: list[np.ndarray]  # per camera, HxW uint8 (object label, 0 elsewhere)


@dataclass
class Run:
    cameras: list[CameraModel]
    joint_names: list[str]
    joint_states: list[tuple[float, list[float]]]
    poses: list[tuple[float, str, np.ndarray, np.ndarray]]  # t, object, position, quaternion x,y,z,w
    frames: list[Frame]
    measured: dict  # quantities measured from the simulation (a bounce's restitution)
    # For `counterfactual`: the engine's state at each frame, the robot's joint angles at each
    # step, and per frame the objects (names) the robot touched in any step to the next frame.
    states: list[np.ndarray] = field(default_factory=list)
    plan: np.ndarray | None = None
    robot_touch: list[set[str]] = field(default_factory=list)


def look_at_quat(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """MuJoCo camera orientation (w, x, y, z): looking along -z with y up, from eye to target."""
    f = target - eye
    f /= np.linalg.norm(f)
    right = np.cross(f, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    mat = np.column_stack([right, up, -f])
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, mat.flatten())
    return q


def inertia(o: Obj) -> tuple[np.ndarray, np.ndarray]:
    """Centre of mass (body frame) and principal moments of the object at uniform density."""
    if o.shape == "cylinder":
        r, h = o.radius, o.half_height
        m = o.true_mass
        i_xy = m * (3 * r * r + 4 * h * h) / 12
        return np.zeros(3), np.array([i_xy, i_xy, m * r * r / 2])
    vols = [8 * p.half[0] * p.half[1] * p.half[2] for p in o.parts]
    total = sum(vols)
    com = sum(np.array(p.centre) * v for p, v in zip(o.parts, vols)) / total
    moments = np.zeros(3)
    for p, v in zip(o.parts, vols):
        m = o.true_mass * v / total
        a, b, c = (2 * np.array(p.half)) ** 2
        d = np.array(p.centre) - com
        # Diagonal of the inertia about the common centre (parallel axes; products neglected).
        moments += m * np.array([(b + c) / 12, (a + c) / 12, (a + b) / 12])
        moments += m * np.array([d[1] ** 2 + d[2] ** 2, d[0] ** 2 + d[2] ** 2, d[0] ** 2 + d[1] ** 2])
    return com, moments


def build(scene: Scene, urdf: str, width: int, height: int, rng: np.random.Generator) -> tuple:
    """The MuJoCo model of `scene`, and its cameras (with a small random jitter of the rig)."""
    spec = mujoco.MjSpec.from_file(urdf)
    spec.compiler.fusestatic = False
    spec.option.timestep = 1.0 / (FRAME_RATE * SUBSTEPS)
    spec.option.gravity = list(scene.gravity)
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.visual.global_.offwidth = width
    spec.visual.global_.offheight = height
    for body in spec.bodies:
        if body.name.startswith("panda"):
            # The arm is driven kinematically; heavy links barely yield to what they push.
            body.mass = max(body.mass, 1e-3) * 50.0
            body.gravcomp = 1.0
    # The engine's one friction for every contact (MuJoCo takes the larger of two): the
    # configuration's, unless the scene hides a different one.
    mu = scene.engine_friction if scene.engine_friction is not None else scene.friction
    for g in spec.geoms:
        g.rgba = [0.92, 0.92, 0.92, 1.0]
        g.friction = [mu, 0.005, 0.0001]
        if scene.stiff_contacts:
            g.solref = list(STIFF_CONTACT)
    spec.body("panda_pusher").add_site(name="tip", pos=list(TIP))
    world = spec.worldbody
    # With a friction patch the floor is frictionless and each object carries the friction of
    # where it stands (MuJoCo takes the larger friction of two touching geoms).
    floor_mu = 0.0 if scene.patch else mu
    world.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1], rgba=[0.55, 0.55, 0.52, 1],
                   friction=[floor_mu, 0.005, 0.0001])
    world.add_light(pos=[0.5, 0.0, 1.5], dir=[0, 0, -1], diffuse=[0.6, 0.6, 0.6], castshadow=False)
    world.add_light(pos=[1.2, -0.8, 1.2], dir=[-0.6, 0.6, -1], diffuse=[0.3, 0.3, 0.3], castshadow=False)
    for o in scene.objects:
        com, moments = inertia(o)
        body = world.add_body(name=o.name, pos=[o.x, o.y, o.half_height_z() + o.z],
                              quat=[math.cos(o.yaw / 2), 0, 0, math.sin(o.yaw / 2)])
        body.add_freejoint()
        body.explicitinertial = True
        body.mass = o.true_mass
        body.ipos = list(com + np.array(o.com_offset))
        body.inertia = list(moments)
        geom = dict(rgba=[*o.colour, 1.0], friction=[mu, 0.005, 0.0001], density=0.0)
        if scene.stiff_contacts:
            geom["solref"] = list(STIFF_CONTACT)
        if scene.restitution is not None:
            geom["solref"] = [0.005, scene.restitution]
        if scene.support == "spread":
            # The visible shape touches the robot and other objects but not the table; hidden
            # spheres under its bottom face carry it (collision bits: table 1, shapes 2, robot 3).
            add_support(body, o, geom)
            geom.update(contype=2, conaffinity=2)
        if o.shape == "cylinder":
            # MuJoCo 4.0's cylinder on the plane loses every contact now and then at rest (dist
            # about 0, margin 0): restitution_3904's cylinder fell 11 mm into the table in 0.05 s,
            # after 1.5 s still, and was thrown 7 cm up. Contacts found a tenth of a millimetre
            # early and left out of the solver until they touch (gap = margin) keep it: the same
            # physics but for that tenth (MuJoCo springs a contact from its margin: the cylinder
            # rests 0.1 mm higher). `sunk_by_robot` skips contacts not touching.
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[o.radius, o.half_height, 0],
                          margin=CYLINDER_WATCH, gap=CYLINDER_WATCH, **geom)
        for p in o.parts:
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, pos=list(p.centre), size=list(p.half), **geom)
    if scene.hand:
        # A fingertip-sized capsule upright, moved as a mocap body: kinematic, seen, not modelled.
        hand = world.add_body(name="hand", mocap=True, pos=list(hand_pose(scene, 0.0)))
        hand.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[HAND_RADIUS, HAND_HALF_LENGTH, 0],
                      rgba=[0.85, 0.62, 0.5, 1.0], friction=[mu, 0.005, 0.0001])
    if scene.support == "spread":
        for g in spec.geoms:
            if g.parent.name.startswith("panda") or g.parent.name == "hand":
                g.contype, g.conaffinity = 3, 3
    fovy = 42.0
    target = np.array([0.5, 0.0, 0.02])
    eyes = [np.array([1.05, -0.45, 0.55]), np.array([1.0, 0.5, 0.6]), np.array([0.3, -0.6, 0.65])]
    names = []
    for k, eye in enumerate(eyes):
        eye = eye + rng.uniform(-0.03, 0.03, 3)
        name = f"cam{k}"
        world.add_camera(name=name, pos=list(eye), quat=list(look_at_quat(eye, target)), fovy=fovy)
        names.append(name)
    model = spec.compile()
    fy = 0.5 * height / math.tan(math.radians(fovy) / 2)
    cameras = [CameraModel(n, width, height, fy, fy, width / 2, height / 2) for n in names]
    return model, cameras


CYLINDER_WATCH = 0.0001  # m a cylinder's contacts are found before they touch (`build`)
SUPPORT_SPACING = 0.015  # m between the support points of a spread support
SUPPORT_RADIUS = 0.004  # m
SUPPORT_BELOW = 0.001  # m the support points reach below the visible shape


def add_support(body, o, geom: dict) -> None:
    """Hidden spheres (geom group 3, not rendered) on a grid under `o`'s bottom face, touching
    only the table: the object bears on the table evenly instead of at its corners."""
    if o.shape == "cylinder":
        bottom, footprints = -o.half_height, [(np.zeros(2), np.array([o.radius, o.radius]), True)]
    else:
        bottom = min(p.centre[2] - p.half[2] for p in o.parts)
        footprints = [(np.array(p.centre[:2]), np.array(p.half[:2]), False) for p in o.parts
                      if abs(p.centre[2] - p.half[2] - bottom) < 1e-6]
    z = bottom + SUPPORT_RADIUS - SUPPORT_BELOW
    for centre, half, round_ in footprints:
        nx, ny = (max(2, round(2 * h / SUPPORT_SPACING)) for h in half)
        for i in range(nx):
            for j in range(ny):
                x = -half[0] + 2 * half[0] * (i + 0.5) / nx
                y = -half[1] + 2 * half[1] * (j + 0.5) / ny
                if round_ and math.hypot(x, y) > half[0] - SUPPORT_RADIUS:
                    continue
                body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[SUPPORT_RADIUS, 0, 0],
                              pos=[centre[0] + x, centre[1] + y, z], group=3, contype=1, conaffinity=1,
                              **{**geom, "rgba": [0, 0, 0, 0]})


def tip_target(scene: Scene, t: float) -> np.ndarray:
    """Where the pusher tip should be at `t` (see `path_target`)."""
    return path_target(scene.pushes, t)


def path_target(pushes: list, t: float) -> np.ndarray:
    """Where a pusher following `pushes` should be at `t`: on a push's line while it pushes, lifted
    between pushes, coming down before the first and backing off and up after the last; parked
    away from the objects without pushes."""
    if not pushes:
        return np.array(PARKED)
    first, last = pushes[0], pushes[-1]
    lift = 0.35  # s to come down to, or up from, a push
    for k, p in enumerate(pushes):
        if p.t0 <= t <= p.t1:
            a = (t - p.t0) / (p.t1 - p.t0)
            return np.array([*(np.array(p.start) * (1 - a) + np.array(p.end) * a), TIP_HEIGHT])
        if k + 1 < len(pushes) and p.t1 < t < pushes[k + 1].t0:
            # Up and back over to the next start.
            q = pushes[k + 1]
            a = (t - p.t1) / (q.t0 - p.t1)
            xy = np.array(p.end) * (1 - a) + np.array(q.start) * a
            return np.array([*xy, TIP_HEIGHT + 0.08 * math.sin(math.pi * a)])
    if t < first.t0:
        # Hovering over the first push's start, then coming down to it.
        a = min(1.0, max(0.0, 1 - (first.t0 - t) / lift))
        above = np.array([*first.start, TIP_HEIGHT + 0.08])
        down = np.array([*first.start, TIP_HEIGHT])
        return above + (down - above) * a
    a = min(1.0, (t - last.t1) / lift)
    end = np.array([*last.end, TIP_HEIGHT])
    # Back off along the push, then up.
    d = np.array(last.end) - np.array(last.start)
    d /= np.linalg.norm(d)
    return end + np.array([*(-0.03 * a * d), 0.1 * a])


HAND_RADIUS = 0.018
HAND_HALF_LENGTH = 0.05


def hand_pose(scene: Scene, t: float) -> np.ndarray:
    """The hand's body position at `t`: its lowest point where a pusher tip would be, or lifted out
    of the way when it has no push to make."""
    tip = path_target(scene.hand, t) if scene.hand else np.array([0.3, 0.35, 0.4])
    return tip + np.array([0.0, 0.0, HAND_RADIUS + HAND_HALF_LENGTH - 0.012])


def solve_ik(model: mujoco.MjModel, data: mujoco.MjData, target: np.ndarray, q: np.ndarray, iterations: int = 60) -> np.ndarray:
    """Joint angles that put the tip at `target` with the rod pointing down (damped least
    squares on MuJoCo's Jacobians, from `q`)."""
    site = model.site("tip").id
    body = model.body("panda_pusher").id
    nq = len(q)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for _ in range(iterations):
        data.qpos[:nq] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        err_p = target - data.site_xpos[site]
        # The link's z axis points up when the rod points down.
        z = data.xmat[body].reshape(3, 3)[:, 2]
        err_r = np.cross(z, [0.0, 0.0, 1.0])
        if np.linalg.norm(err_p) < 1e-5 and np.linalg.norm(err_r) < 1e-4:
            break
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        J = np.vstack([jacp[:, :nq], jacr[:, :nq]])
        e = np.concatenate([err_p, err_r])
        dq = J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(6), e)
        q = q + dq
        q = np.clip(q, model.jnt_range[:nq, 0], model.jnt_range[:nq, 1])
    return q


def robot_plan(model: mujoco.MjModel, scene: Scene, times: np.ndarray, q: np.ndarray | None = None) -> np.ndarray:
    """Joint angles at each time of `times` (IK warm-started from the previous one, the first
    from `q` or from home)."""
    data = mujoco.MjData(model)
    nq = 7
    if q is None:
        q = solve_ik(model, data, tip_target(scene, float(times[0])), np.array(HOME), 300)
    out = np.zeros((len(times), nq))
    for k, t in enumerate(times):
        q = solve_ik(model, data, tip_target(scene, t), q)
        out[k] = q
    return out


def label_image(model: mujoco.MjModel, seg: np.ndarray, labels: dict[int, int]) -> np.ndarray:
    """Instance labels from MuJoCo's segmentation (geom ids) through the geoms' bodies."""
    ids, types = seg[..., 0], seg[..., 1]
    out = np.zeros(ids.shape, np.uint8)
    geom = types == int(mujoco.mjtObj.mjOBJ_GEOM)
    for body, label in labels.items():
        geoms = np.flatnonzero(model.geom_bodyid == body)
        out[geom & np.isin(ids, geoms)] = label
    return out


def apply_effects(model: mujoco.MjModel, data: mujoco.MjData, scene: Scene, bodies: list[int]) -> None:
    """The hidden effect as the engine applies it, before a step."""
    data.xfrc_applied[:] = 0.0
    first = bodies[0]
    if scene.drag:
        v = np.zeros(6)
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, first, v, 0)
        data.xfrc_applied[first, :3] = -scene.drag * v[3:]
    if scene.spring:
        s = scene.spring
        point = data.xpos[first] + data.xmat[first].reshape(3, 3) @ np.array(s["point"])
        d = np.array(s["anchor"]) - point
        n = np.linalg.norm(d)
        if n > s["rest_length"]:
            f = s["stiffness"] * (n - s["rest_length"]) * d / n
            data.xfrc_applied[first, :3] = f
            # Applied at `point`, not at the centre of mass: add its torque.
            data.xfrc_applied[first, 3:] = np.cross(point - data.xipos[first], f)
    if scene.patch:
        p = scene.patch
        for body in bodies:
            inside = np.dot(data.xipos[body][:2] - np.array(p["edge_point"]), p["normal"]) > 0
            mu = p["friction"] if inside else scene.friction
            model.geom_friction[model.geom_bodyid == body, 0] = mu


def heading(quat_wxyz: np.ndarray) -> float:
    """A body's turn about the vertical from MuJoCo's quaternion (w, x, y, z)."""
    w, x, y, z = quat_wxyz
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


# Furthest (m) from where a later push was first aimed that it follows its object.
FOLLOW_WITHIN = 0.2


def follow(push, place: tuple[float, float, float]) -> None:
    """Move `push` (in place) with its object from where it was aimed (`push.aim`: x, y, yaw) to
    `place`: the same line through the object, turned with it."""
    ax, ay, ayaw = push.aim
    x, y, yaw = place
    c, s = math.cos(yaw - ayaw), math.sin(yaw - ayaw)

    def moved(p):
        dx, dy = p[0] - ax, p[1] - ay
        return (x + c * dx - s * dy, y + s * dx + c * dy)

    push.start, push.end = moved(push.start), moved(push.end)
    push.aim = place


def push_start(push, scene: Scene, data: mujoco.MjData, bodies: list[int], key: str) -> dict:
    """Where a push's tip comes down, against the objects as they are then: `gap_m`, the distance
    along the push from the tip's centre to the first object's outline (None where its line
    misses it), and `inside`, the objects the rod (or hand) overlaps already."""
    radius = HAND_RADIUS if key == "hand" else ROD_RADIUS
    d = np.array(push.end) - np.array(push.start)
    d = tuple(d / np.linalg.norm(d))
    gap, inside = None, []
    for i, (o, b) in enumerate(zip(scene.objects, bodies)):
        now = replace(o, x=float(data.xpos[b][0]), y=float(data.xpos[b][1]), yaw=heading(data.xquat[b]))
        chord = now.chord(push.start, d)
        if i == 0 and chord is not None:
            gap = chord[0]
        grown = now.chord(push.start, d, -radius)
        if grown is not None and grown[0] < 0.0 < grown[1]:
            inside.append(o.name)
    return {"gap_m": gap, "inside": inside}


def simulate(scene: Scene, urdf: str, width: int, height: int) -> Run:
    rng = np.random.default_rng(zlib.crc32(f"{scene.kind}/{scene.seed}".encode()))
    model, cameras = build(scene, urdf, width, height, rng)
    data = mujoco.MjData(model)
    nq = 7
    bodies = [model.body(o.name).id for o in scene.objects]
    labels = {b: o.label for b, o in zip(bodies, scene.objects)}
    dt = model.opt.timestep
    steps = int(round(scene.duration * FRAME_RATE)) * SUBSTEPS
    times = np.arange(steps + 1) * dt
    plan = robot_plan(model, scene, times)
    data.qpos[:nq] = plan[0]
    mujoco.mj_forward(model, data)
    for cam in cameras:
        c = model.camera(cam.name).id
        cam.position = data.cam_xpos[c].copy()
        # MuJoCo's camera frame looks along -z with y up; the optical frame is it turned by pi about x.
        cam.rotation = data.cam_xmat[c].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
    renderer = mujoco.Renderer(model, height, width)
    run = Run(cameras, [model.joint(j).name for j in range(nq)], [], [], [], {})
    impacts = []
    # The next push of the robot and of the hand that moves with its object (`Scene.follow`):
    # through the pause before it, aimed at where the object is (an arm does not jump, so the
    # tip's way over bends towards it); from its start on, fixed.
    following = {"pushes": 1, "hand": 1}
    robot_geom = np.array([model.body(int(b)).name.startswith("panda") for b in model.geom_bodyid])
    names = {b: o.name for b, o in zip(bodies, scene.objects)}
    state_kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    ik = mujoco.MjData(model)
    # Each push's start as it came: how far its tip is from the object along its line.
    begun = {"pushes": 0, "hand": 0}
    run.measured["starts"] = {"pushes": [], "hand": []}
    # How far the driven robot sinks into each object it touches (`sunk_by_robot`).
    run.measured["sunk"] = {}
    for k in range(steps + 1):
        t = k * dt
        for key in begun:
            pushes = getattr(scene, key)
            if begun[key] < len(pushes) and t >= pushes[begun[key]].t0:
                run.measured["starts"][key].append(push_start(pushes[begun[key]], scene, data, bodies, key))
                begun[key] += 1
        for key in following if scene.follow else ():
            pushes = getattr(scene, key)
            j = following[key]
            if j >= len(pushes) or t < pushes[j - 1].t1 or pushes[j].aim is None:
                continue
            b = bodies[0]
            place = (float(data.xpos[b][0]), float(data.xpos[b][1]), heading(data.xquat[b]))
            # An object that slid far away (off the table) is not chased: the push goes back to
            # where it was planned (left where the object was last followed, its rod could come
            # down on it as it slides to rest).
            near = math.dist(place[:2], pushes[j].planned[:2]) < FOLLOW_WITHIN
            follow(pushes[j], place if near else pushes[j].planned)
            started = t >= pushes[j].t0
            if key == "pushes" and k < steps:
                if started:
                    plan[k + 1:] = robot_plan(model, scene, times[k + 1:], plan[k])
                elif k % SUBSTEPS == 0:
                    # A frame ahead by inverse kinematics, the steps between in a straight line.
                    n = min(SUBSTEPS, steps - k)
                    q = solve_ik(model, ik, tip_target(scene, float(times[k + n])), plan[k])
                    plan[k + 1:k + n + 1] = plan[k] + np.outer(np.arange(1, n + 1) / n, q - plan[k])
            if started:
                following[key] = j + 1
        if k % JOINT_RATE_DIVIDER == 0:
            run.joint_states.append((t, [float(v) for v in data.qpos[:nq]]))
        if k % SUBSTEPS == 0:
            for o, b in zip(scene.objects, bodies):
                run.poses.append((t, o.name, data.xpos[b].copy(), np.roll(data.xquat[b], -1).copy()))
            run.frames.append(render(renderer, model, data, cameras, labels, t))
            state = np.empty(mujoco.mj_stateSize(model, state_kind))
            mujoco.mj_getState(model, data, state, state_kind)
            run.states.append(state)
            run.robot_touch.append(set())
        if k == steps:
            break
        apply_effects(model, data, scene, bodies)
        if scene.hand:
            data.mocap_pos[0] = hand_pose(scene, t + dt)
        # Kinematic robot: the plan's angles and velocities, whatever the contacts did.
        data.qpos[:nq] = plan[k]
        data.qvel[:nq] = (plan[k + 1] - plan[k]) / dt
        vz_before = data.qvel[nq + 2] if scene.restitution is not None else 0.0
        mujoco.mj_step(model, data)
        sunk_now = sunk_by_robot(data, robot_geom, model.geom_bodyid, names)
        run.robot_touch[-1].update(sunk_now)
        for name, depth in sunk_now.items():
            sunk = run.measured["sunk"].setdefault(name, {"deepest_m": 0.0, "frames_over_3mm": 0.0})
            sunk["deepest_m"] = max(sunk["deepest_m"], depth)
            sunk["frames_over_3mm"] += (depth > 0.003) / SUBSTEPS
        if scene.restitution is not None:
            vz = data.qvel[nq + 2]
            impacts.append((vz_before, vz))
    renderer.close()
    run.plan = plan
    if scene.restitution is not None:
        run.measured["restitution"] = bounce_restitution(impacts)
    return run


def sunk_by_robot(data: mujoco.MjData, robot_geom: np.ndarray, geom_body: np.ndarray,
                  names: dict[int, str]) -> dict[str, float]:
    """Per object (by name) the robot is in contact with in `data` (the objects it touches), how
    deep (m) the robot is inside it, its deepest contact. MuJoCo's contacts are soft and the arm is
    driven whatever they do: a rod that strikes an object passes into it for a few frames before it
    pushes it away, where a rigid model (pegs's) has the object outside the rod, so the truth there
    is a pose no rigid tracker can reach."""
    out: dict[str, float] = {}
    for c in data.contact[:data.ncon]:
        a, b = int(c.geom1), int(c.geom2)
        if robot_geom[a] == robot_geom[b] or c.dist > 0.0:
            continue
        other = geom_body[b] if robot_geom[a] else geom_body[a]
        if other in names:
            out[names[other]] = max(out.get(names[other], 0.0), -float(c.dist))
    return out


def bounce_restitution(vz: list[tuple[float, float]]) -> float:
    """The first bounce's coefficient: the largest upward speed after the first impact over the
    fastest downward speed before it."""
    down = [a for a, _ in vz]
    k = int(np.argmin(down))
    v_in = -down[k]
    v_out = max(b for _, b in vz[k:k + 200])
    return float(max(v_out, 0.0) / v_in)


def render(renderer, model, data, cameras, labels, t) -> Frame:
    frame = Frame(t, [], [], [])
    for cam in cameras:
        renderer.update_scene(data, camera=cam.name)
        frame.rgb.append(renderer.render().copy())
        renderer.enable_depth_rendering()
        depth = renderer.render().astype(np.float32)
        renderer.disable_depth_rendering()
        depth[depth > 10.0] = 0.0
        frame.depth.append(depth)
        renderer.enable_segmentation_rendering()
        frame.labels.append(label_image(model, renderer.render(), labels))
        renderer.disable_segmentation_rendering()
    return frame

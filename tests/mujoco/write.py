"""A simulated run (simulate.py) written as a rig would record it, with a third-party writer
(PyPI `rosbags`): a rosbag2 directory (MCAP or SQLite3 storage) on realsense2_camera's topics
(`/camera/{camera}/color/...`, `/camera/{camera}/aligned_depth_to_color/image_raw`), CameraInfo and
the arm's /joint_states. Two layouts:

- `pegs`: raw rgb8 colour, depth (32FC1 metres or 16UC1 millimetres), instance labels (mono8),
  each optical frame straight from `world` on /tf_static;
- `realsense`: what a RealSense + Franka rig records: JPEG colour on `.../image_raw/compressed`
  only, 16UC1 millimetre depth, no masks, the tf chain the drivers publish
  (`world -> {camera}_link` by the user, `{camera}_link -> {camera}_color_frame ->
  {camera}_color_optical_frame` by realsense2_camera).

Beside the bag: the ground truth (`ground_truth.csv`, pegs's layout), the hidden truth
(`truth.json`) and the configuration a user would write (`config.yaml`: cameras, objects as the
user believes them, the robot). Owns the files only.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from scenes import Scene
from simulate import Run

TYPES = get_typestore(Stores.ROS2_JAZZY)
Header = TYPES.types["std_msgs/msg/Header"]
Time = TYPES.types["builtin_interfaces/msg/Time"]
Image = TYPES.types["sensor_msgs/msg/Image"]
CompressedImage = TYPES.types["sensor_msgs/msg/CompressedImage"]
CameraInfo = TYPES.types["sensor_msgs/msg/CameraInfo"]
RegionOfInterest = TYPES.types["sensor_msgs/msg/RegionOfInterest"]
JointState = TYPES.types["sensor_msgs/msg/JointState"]
TFMessage = TYPES.types["tf2_msgs/msg/TFMessage"]
TransformStamped = TYPES.types["geometry_msgs/msg/TransformStamped"]
Transform = TYPES.types["geometry_msgs/msg/Transform"]
Vector3 = TYPES.types["geometry_msgs/msg/Vector3"]
Quaternion = TYPES.types["geometry_msgs/msg/Quaternion"]


def header(t: float, frame: str):
    sec = math.floor(t)
    return Header(stamp=Time(sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000), frame_id=frame)


def quat_xyzw(r: np.ndarray) -> list[float]:
    """A rotation matrix as a unit quaternion x, y, z, w."""
    w = math.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return [x / n, y / n, z / n, w / n]


def image(t: float, frame: str, data: np.ndarray, encoding: str, step: int):
    h, w = data.shape[:2]
    return Image(header=header(t, frame), height=h, width=w, encoding=encoding, is_bigendian=0, step=step,
                 data=np.frombuffer(np.ascontiguousarray(data).tobytes(), np.uint8))


def camera_info(t: float, frame: str, c) -> object:
    return CameraInfo(
        header=header(t, frame), height=c.height, width=c.width, distortion_model="plumb_bob",
        d=np.zeros(5), k=np.array([c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1], float),
        r=np.eye(3).flatten(), p=np.array([c.fx, 0, c.cx, 0, 0, c.fy, c.cy, 0, 0, 0, 1, 0], float),
        binning_x=0, binning_y=0,
        roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def depth_image(t: float, frame: str, depth: np.ndarray, encoding: str):
    """Depth as 32FC1 metres, or as 16UC1 millimetres as realsense2_camera publishes it."""
    if encoding == "16UC1":
        mm = np.clip(np.round(depth * 1000.0), 0, 65535).astype("<u2")
        return image(t, frame, mm, "16UC1", 2 * depth.shape[1])
    return image(t, frame, depth.astype("<f4"), "32FC1", 4 * depth.shape[1])


def compressed(t: float, frame: str, rgb: np.ndarray):
    """JPEG colour as image_transport's `compressed` plugin publishes it."""
    from io import BytesIO

    from PIL import Image as Picture
    buffer = BytesIO()
    Picture.fromarray(np.ascontiguousarray(rgb)).save(buffer, format="JPEG", quality=90)
    return CompressedImage(header=header(t, frame), format="rgb8; jpeg compressed bgr8",
                           data=np.frombuffer(buffer.getvalue(), np.uint8))


def transform(t: float, parent: str, child: str, position, rotation: np.ndarray):
    q = quat_xyzw(rotation)
    return TransformStamped(
        header=header(t, parent), child_frame_id=child,
        transform=Transform(translation=Vector3(x=float(position[0]), y=float(position[1]), z=float(position[2])),
                            rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])))


# realsense2_camera's fixed links: the colour sensor 15 mm along the camera link's y, and the
# optical frame (z forward, x right, y down) turned from the link's x forward, z up.
COLOUR_OFFSET = np.array([0.0, 0.015, 0.0])
LINK_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera_transforms(run: Run, stamp0: float, layout: str) -> list:
    """/tf_static: each optical frame from `world` (pegs), or the realsense chain (realsense)."""
    out = []
    for c in run.cameras:
        optical = f"{c.name}_color_optical_frame"
        if layout == "pegs":
            out.append(transform(stamp0, "world", optical, c.position, c.rotation))
            continue
        # world_from_link = world_from_optical * (link_from_optical)^-1, colour frame offset by
        # COLOUR_OFFSET in the link (no rotation between link and colour frame).
        world_from_link_r = c.rotation @ LINK_FROM_OPTICAL.T
        world_from_link_p = np.asarray(c.position) - world_from_link_r @ COLOUR_OFFSET
        out.append(transform(stamp0, "world", f"{c.name}_link", world_from_link_p, world_from_link_r))
        out.append(transform(stamp0, f"{c.name}_link", f"{c.name}_color_frame", COLOUR_OFFSET, np.eye(3)))
        out.append(transform(stamp0, f"{c.name}_color_frame", optical, np.zeros(3), LINK_FROM_OPTICAL))
    return out


def write_bag(path: Path, run: Run, stamp0: float, depth_encoding: str = "32FC1", layout: str = "pegs",
              storage: str = "mcap") -> None:
    """The rosbag2 directory `path` in `layout` with `storage` (mcap or sqlite3)."""
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    realsense = layout == "realsense"
    if realsense:
        depth_encoding = "16UC1"
    with Writer(path, version=9, storage_plugin=plugin) as w:
        def connect(topic, msgtype):
            return w.add_connection(topic, msgtype, typestore=TYPES)

        tf = connect("/tf_static", "tf2_msgs/msg/TFMessage")
        joints = connect("/joint_states", "sensor_msgs/msg/JointState")
        per_camera = {}
        for c in run.cameras:
            base = f"/camera/{c.name}"
            per_camera[c.name] = dict(
                info=connect(f"{base}/color/camera_info", "sensor_msgs/msg/CameraInfo"),
                depth=connect(f"{base}/aligned_depth_to_color/image_raw", "sensor_msgs/msg/Image"),
            )
            if realsense:
                per_camera[c.name]["jpeg"] = connect(f"{base}/color/image_raw/compressed", "sensor_msgs/msg/CompressedImage")
            else:
                per_camera[c.name]["rgb"] = connect(f"{base}/color/image_raw", "sensor_msgs/msg/Image")
                per_camera[c.name]["mask"] = connect(f"{base}/mask/image_raw", "sensor_msgs/msg/Image")

        def put(conn, t, msg, msgtype):
            w.write(conn, int(round((stamp0 + t) * 1e9)), TYPES.serialize_cdr(msg, msgtype))

        put(tf, 0.0, TFMessage(transforms=camera_transforms(run, stamp0, layout)), "tf2_msgs/msg/TFMessage")
        # Messages in time order, as a recorder receives them.
        events = [(t, 0, k) for k, (t, _) in enumerate(run.joint_states)]
        events += [(f.t, 1, k) for k, f in enumerate(run.frames)]
        for t, kind, k in sorted(events):
            if kind == 0:
                msg = JointState(header=header(stamp0 + t, ""), name=run.joint_names, position=np.array(run.joint_states[k][1]),
                                 velocity=np.zeros(0), effort=np.zeros(0))
                put(joints, t, msg, "sensor_msgs/msg/JointState")
                continue
            frame = run.frames[k]
            for i, c in enumerate(run.cameras):
                optical = f"{c.name}_color_optical_frame"
                conns = per_camera[c.name]
                put(conns["info"], t, camera_info(stamp0 + t, optical, c), "sensor_msgs/msg/CameraInfo")
                if realsense:
                    put(conns["jpeg"], t, compressed(stamp0 + t, optical, frame.rgb[i]), "sensor_msgs/msg/CompressedImage")
                else:
                    put(conns["rgb"], t, image(stamp0 + t, optical, frame.rgb[i], "rgb8", 3 * c.width), "sensor_msgs/msg/Image")
                    put(conns["mask"], t, image(stamp0 + t, optical, frame.labels[i], "mono8", c.width), "sensor_msgs/msg/Image")
                put(conns["depth"], t, depth_image(stamp0 + t, optical, frame.depth[i], depth_encoding), "sensor_msgs/msg/Image")


def write_truth(out: Path, scene: Scene, run: Run, stamp0: float) -> None:
    lines = ["t,object,x,y,z,qx,qy,qz,qw"]
    for t, name, p, q in run.poses:
        lines.append(f"{stamp0 + t:.6f},{name},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},{q[0]:.7f},{q[1]:.7f},{q[2]:.7f},{q[3]:.7f}")
    (out / "ground_truth.csv").write_text("\n".join(lines) + "\n")
    truth = dict(scene.truth)
    if scene.kind == "restitution":
        truth["parameter"] = run.measured["restitution"]
    if "shown" in run.measured:
        # What the recording can show of the effect (counterfactual.py), per object.
        truth["shown"] = run.measured["shown"]
    # Per object the robot touched: how deep its rod went into it, and for how many frames over
    # 3 mm (`simulate.sunk_by_robot`): poses there a rigid model cannot take.
    truth["robot_sunk"] = {name: dict(deepest_mm=round(v["deepest_m"] * 1e3, 2),
                                      frames_over_3mm=round(v["frames_over_3mm"], 2))
                           for name, v in run.measured.get("sunk", {}).items()}
    first = run.poses[0]
    truth.update(kind=scene.kind, seed=scene.seed, shape=scene.shape, duration=scene.duration,
                 friction=scene.friction, stamp0=stamp0, support=scene.support,
                 stiff_contacts=scene.stiff_contacts,
                 objects=[dict(name=o.name, shape=o.shape, mass=o.mass, true_mass=o.true_mass,
                               com_offset=list(o.com_offset)) for o in scene.objects],
                 pushes=[dict(t0=p.t0, t1=p.t1, start=list(p.start), end=list(p.end), **came)
                         for p, came in zip(scene.pushes, run.measured["starts"]["pushes"])],
                 hand=[dict(t0=p.t0, t1=p.t1, start=list(p.start), end=list(p.end), **came)
                       for p, came in zip(scene.hand, run.measured["starts"]["hand"])],
                 start_pose={"object": first[1], "position": list(map(float, first[2])), "quaternion_xyzw": list(map(float, first[3]))})
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")


def write_config(out: Path, scene: Scene, urdf: Path, cameras: list[str]) -> None:
    """What a user knows: the cameras, the table's friction, the objects' masses (as
    configured), the robot. The table is configured over the floor the robot works on and the
    cameras see (0.8 x 0.9 m): a 0.6 m square left slippery tables' slides beyond its edge (a box
    resting 3.5 cm past it, tracked 13 mm off, 7 mm with the wider table)."""
    objects = "\n".join(f"        - {{name: {o.name}, label: {o.label}, mass: {o.mass}, particle_radius: 0.005}}" for o in scene.objects)
    mu = scene.friction
    (out / "config.yaml").write_text(f"""pegs:
  ros__parameters:
    physics:
      ground: {{static_friction: {mu}, kinetic_friction: {mu}}}
      collisions: {{static_friction: {mu}, kinetic_friction: {mu}}}
    robot:
      urdf: {urdf}
    node:
      cameras: [{", ".join(cameras)}]
    scene:
      rgbd_objects:
{objects}
      ground_from_depth: true
      table: {{min: [0.1, -0.45], max: [0.9, 0.45], fit_steps: 60, lr: 0.05, drop: 0.0}}
""")

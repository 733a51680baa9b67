"""rclpy integration tests of `pegs node` (run by tests/ros/run.sh inside a loopback-only netns).

A generated scenario (pushed_box) is played into the node in real time by Python publishers while
Python subscribers record what the node publishes. During the main run the player also sends every
kind of bad input the node must survive; the tests then check that outputs kept coming at rate,
that the tracked box followed the scenario's ground truth, and that each bad input was refused,
counted and reported in /diagnostics. A second run leaves one camera without CameraInfo.
"""
import csv
import json
import math
import os
import re
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from pegs_msgs.msg import TrackedObjectArray
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.msg import ParameterEvent
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState, PointCloud2
from tf2_msgs.msg import TFMessage

ROOT = Path(os.environ.get("PEGS_ROOT", Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(ROOT / "launch_scripts"))
from play_recording import LATCHED, RELIABLE, SENSOR, Player, restamped  # noqa: E402

PEGS = os.environ["PEGS_BIN"]
RUN_SECONDS = 4.5  # the scenario's length


def stamp_of(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def set_stamp(msg, t: float):
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9)) % 1_000_000_000
    return msg


@pytest.fixture(scope="module")
def recording():
    out = Path(tempfile.mkdtemp(prefix="pegs-ros-"))
    subprocess.run([PEGS, "scenario", "generate", "pushed_box", "--out", str(out), "--width", "160", "--height", "90"], check=True, stdout=subprocess.DEVNULL)
    return out


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


class Recorder:
    """Subscribes to every output of the node and keeps (receive time, message)."""

    def __init__(self, node):
        self.got = {}
        self.node = node

        def keep(name):
            return lambda msg: self.got.setdefault(name, []).append((time.time(), msg))

        node.create_subscription(TrackedObjectArray, "/pegs/objects", keep("objects"), 50)
        node.create_subscription(PoseArray, "/pegs/poses", keep("poses"), 50)
        node.create_subscription(PointCloud2, "/pegs/particles", keep("particles"), qos_profile_sensor_data)
        node.create_subscription(Image, "/pegs/debug/cam0/image", keep("debug"), qos_profile_sensor_data)
        node.create_subscription(CompressedImage, "/pegs/debug/cam0/image/compressed", keep("debug_compressed"), qos_profile_sensor_data)
        node.create_subscription(DiagnosticArray, "/diagnostics", keep("diagnostics"), 50)
        node.create_subscription(TFMessage, "/tf", keep("tf"), 100)

    def count(self, name):
        return len(self.got.get(name, []))


def start_node(recording: Path, log_name: str, extra=()):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    stats = recording / f"{log_name}.stats.json"
    log = open(recording / f"{log_name}.log", "w")
    proc = subprocess.Popen(
        [PEGS, "node", "--config", str(recording / "config.yaml"), "--stats", str(stats), "--ros-args", "-p", "node.debug_images_every:=3", *extra],
        env=env, stdout=log, stderr=subprocess.STDOUT,
    )
    return proc, stats


def stop_node(proc, stats: Path) -> dict:
    proc.send_signal(2)
    proc.wait(timeout=30)
    assert proc.returncode == 0, f"node exited with {proc.returncode}"
    return json.loads(stats.read_text())


def spin_for(node, seconds: float, player=None, each=None):
    end = time.time() + seconds
    while time.time() < end:
        if player is not None:
            player.publish_due(time.time())
        if each is not None:
            each(time.time())
        rclpy.spin_once(node, timeout_sec=0.003)


def wait_for_discovery(node, player, timeout: float = 20.0):
    """Until the node has matched every topic the player publishes and we have matched its outputs."""
    topics = set(player.publishers) | {"/tf_static"}
    end = time.time() + timeout

    def pending():
        return [t for t in topics if node.count_subscribers(t) == 0] + [t for t in ["/pegs/objects", "/diagnostics"] if node.count_publishers(t) == 0]

    while time.time() < end and pending():
        rclpy.spin_once(node, timeout_sec=0.05)
    assert not pending(), f"not discovered: {pending()}"
    spin_for(node, 0.5)  # let the readers match the writers too


def call(node, client, request, timeout=10.0):
    assert client.wait_for_service(timeout_sec=timeout), f"service {client.srv_name} not available"
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    assert future.done(), f"no answer from {client.srv_name}"
    return future.result()


@pytest.fixture(scope="module")
def main_run(recording, ros):
    """Play the scenario with faults injected; record outputs; stop the node."""
    node = rclpy.create_node("pegs_test_main")
    recorder = Recorder(node)
    proc, stats_path = start_node(recording, "main")
    player = Player(node, str(recording / "recording"))
    image_pub = node.create_publisher(Image, "/camera/cam0/color/image_raw", SENSOR)
    image1_pub = node.create_publisher(Image, "/camera/cam1/color/image_raw", SENSOR)
    joints_pub = player.publishers["/joint_states"]
    wait_for_discovery(node, player)
    # A good image to copy faults from.
    template = next(m for m in player.messages if m[1] == "/camera/cam0/color/image_raw")
    from rclpy.serialization import deserialize_message
    good = deserialize_message(template[3], Image)
    joint_names = deserialize_message(next(m for m in player.messages if m[1] == "/joint_states")[3], JointState).name

    start = time.time() + 1.0
    player.begin(start)
    sent = []

    def fault(name, at, action):
        return [name, start + at, action]

    def wrong_encoding(now):
        img = Image(header=good.header, height=good.height, width=good.width, encoding="mono8", is_bigendian=0, step=good.width, data=bytes(good.width * good.height))
        image_pub.publish(set_stamp(img, now))

    def wrong_size(now):
        img = Image(header=good.header, height=good.height // 2, width=good.width, encoding="rgb8", is_bigendian=0, step=good.width * 3, data=bytes(good.width * 3 * (good.height // 2)))
        image1_pub.publish(set_stamp(img, now))

    def nan_joints(now):
        joints_pub.publish(set_stamp(JointState(name=list(joint_names), position=[float("nan")] * len(joint_names)), now))

    def unknown_joint(now):
        joints_pub.publish(set_stamp(JointState(name=["mystery_joint"], position=[0.3]), now))

    def backwards(now):
        image_pub.publish(set_stamp(good, now - 5.0))

    def future(now):
        image_pub.publish(set_stamp(good, now + 30.0))

    def malformed(now):
        # Valid encapsulation header, then a string length far past the end of the data.
        image1_pub.publish(b"\x00\x01\x00\x00" + struct.pack("<iII", 1, 2, 0x7FFFFFF0) + b"xyz")

    def burst(now):
        for k in range(300):
            image_pub.publish(set_stamp(good, now - 0.2 + k * 1e-5))

    def stop_cam2(now):
        player.paused_topics.add("/camera/cam2/")

    faults = [
        fault("wrong_encoding", 0.5, wrong_encoding),
        fault("wrong_size", 0.7, wrong_size),
        fault("nan_joints", 0.9, nan_joints),
        fault("unknown_joint", 1.1, unknown_joint),
        fault("backwards", 1.3, backwards),
        fault("future", 1.5, future),
        fault("malformed", 1.7, malformed),
        fault("burst", 1.9, burst),
        fault("stop_cam2", 2.5, stop_cam2),
    ]

    def inject(now):
        for f in faults:
            if f[1] is not None and now >= f[1]:
                f[2](now)
                sent.append((f[0], now))
                f[1] = None

    spin_for(node, (start - time.time()) + RUN_SECONDS + 1.5, player, inject)

    # Parameters through the standard services, while the node runs.
    params = {"events": []}
    node.create_subscription(ParameterEvent, "/parameter_events", params["events"].append, 50)
    listed = call(node, node.create_client(ListParameters, "/pegs/list_parameters"), ListParameters.Request())
    params["names"] = list(listed.result.names)
    get = node.create_client(GetParameters, "/pegs/get_parameters")
    params["gain_before"] = call(node, get, GetParameters.Request(names=["correct.gain"])).values[0].double_value
    setter = node.create_client(SetParameters, "/pegs/set_parameters")

    def set_param(name, value):
        p = Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))
        return call(node, setter, SetParameters.Request(parameters=[p])).results[0]

    params["set_at"] = time.time()
    params["set_gain"] = set_param("correct.gain", 800.0)
    params["set_dt"] = set_param("physics.dt", 0.01)
    params["set_bad_gain"] = set_param("correct.gain", -1.0)
    params["gain_after"] = call(node, get, GetParameters.Request(names=["correct.gain"])).values[0].double_value
    params["dt_after"] = call(node, get, GetParameters.Request(names=["physics.dt"])).values[0].double_value
    describe = node.create_client(DescribeParameters, "/pegs/describe_parameters")
    names = ["correct.gain", "physics.dt", "use_sim_time"]
    params["described"] = call(node, describe, DescribeParameters.Request(names=names)).descriptors
    spin_for(node, 1.5)
    stats = stop_node(proc, stats_path)
    node.destroy_node()
    return {"recorder": recorder, "player": player, "stats": stats, "sent": dict(sent), "start": start, "params": params, "log": (recording / "main.log").read_text(), "recording": recording}


def configured_gain(recording: Path) -> float:
    """correct.gain in the recording's configuration (the node's gain before any change)."""
    text = (recording / "config.yaml").read_text()
    section = text[text.index("correct:"):]
    return float(re.search(r"\n\s+gain:\s*([-0-9.eE+]+)", section).group(1))


def ground_truth(recording: Path):
    rows = list(csv.DictReader(open(recording / "ground_truth.csv")))
    return [(float(r["t"]), float(r["x"]), float(r["y"]), float(r["z"])) for r in rows if r["object"] == "box"]


def truth_at(track, t):
    return min(track, key=lambda r: abs(r[0] - t))


def box_errors(objects, player, recording: Path, until: float = RUN_SECONDS):
    """Distances (m) of the tracked box from the ground truth, for (receive time, message) pairs
    whose recording time lies in [1 s, until]."""
    track = ground_truth(recording)
    errors = []
    for _, msg in objects:
        t = player.recording_time(stamp_of(msg))
        if 1.0 <= t <= until:
            (box,) = [o for o in msg.objects if o.name == "box"]
            _, x, y, z = truth_at(track, t)
            errors.append(math.dist((box.pose.position.x, box.pose.position.y, box.pose.position.z), (x, y, z)))
    return errors


def level(status) -> int:
    """diagnostic_msgs levels are `byte`: rclpy gives bytes."""
    return status.level[0] if isinstance(status.level, bytes) else int(status.level)


def last_diagnostics(run):
    """The last /diagnostics while the recording still played, after cam2 had stopped."""
    start = run["start"]
    during = [m for _, m in run["recorder"].got["diagnostics"] if start + 3.1 <= stamp_of(m) <= start + RUN_SECONDS]
    assert during, "no diagnostics in the last part of the playback"
    return {s.name: s for s in during[-1].status}


def tick_counters(msg):
    """(tick time, ticks run, ticks skipped, outputs dropped) from a /diagnostics message."""
    (tick,) = [s for s in msg.status if s.name == "pegs: tick"]
    values = {kv.key: kv.value for kv in tick.values}
    return stamp_of(msg), int(values["ticks"]), int(values["skipped_ticks"]), int(values["dropped_outputs"])


def test_the_tick_clock_keeps_its_rate_and_every_tick_is_published(main_run):
    rec, start = main_run["recorder"], main_run["start"]
    stamps = [stamp_of(m) for _, m in rec.got.get("objects", []) if start <= stamp_of(m) <= start + RUN_SECONDS]
    rate = len(stamps) / RUN_SECONDS
    print(f"objects at {rate:.1f} Hz during playback; node stats {json.dumps(main_run['stats'])}")
    # The clock ticks at 30 Hz whatever a tick costs: a tick whose deadline passed is skipped (and
    # counted), never queued. How many ticks a machine runs is a benchmark (`pegs bench tick`);
    # here the node must stay alive under load (a stalled node publishes nothing) and account for
    # every period of its clock.
    assert len(stamps) >= 5, f"{len(stamps)} poses during playback"
    dt = 1.0 / 30.0
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps), "tick stamps go forward"
    off_grid = [b - a for a, b in zip(stamps, stamps[1:]) if abs((b - a) / dt - round((b - a) / dt)) > 0.01]
    assert not off_grid, f"poses between ticks of the 30 Hz clock: {off_grid[:5]}"
    # A node started on a loaded machine may still report its start-up ("pegs: start-up", waiting
    # for a camera) after the playback began: only the messages of the running clock count.
    ticking = [m for _, m in rec.got["diagnostics"]
               if start <= stamp_of(m) <= start + RUN_SECONDS and any(s.name == "pegs: tick" for s in m.status)]
    counters = [tick_counters(m) for m in ticking]
    assert len(counters) >= 2, "tick diagnostics during playback"
    (t0, ran0, skipped0, dropped0), (t1, ran1, skipped1, dropped1) = counters[0], counters[-1]
    periods = round((t1 - t0) / dt)
    assert (ran1 + skipped1) - (ran0 + skipped0) == periods, "every period of the clock is run or counted as skipped"
    # Every tick that ran was published (or counted as dropped by the publishing thread).
    published = sum(1 for t in stamps if t0 < t <= t1)
    assert published >= (ran1 - ran0) - (dropped1 - dropped0) - 1, f"{published} poses for {ran1 - ran0} ticks"
    assert rec.count("objects") >= 0.9 * main_run["stats"]["ticks"]
    for name in ["poses", "particles", "tf"]:
        assert rec.count(name) >= 0.7 * rec.count("objects"), f"{name}: {rec.count(name)} vs {rec.count('objects')} object messages"
    # Large best-effort images may be lost under load; some must arrive.
    assert rec.count("debug") >= 3 and rec.count("debug_compressed") >= 3, "debug images every third tick"
    assert rec.count("diagnostics") >= 3


def test_tracked_box_follows_the_ground_truth(main_run, recording):
    track = ground_truth(recording)
    errors = box_errors(main_run["recorder"].got["objects"], main_run["player"], recording)
    assert len(errors) >= 8, f"{len(errors)} poses during the push"
    mean_mm = 1e3 * sum(errors) / len(errors)
    moved_mm = 1e3 * math.dist(track[0][1:], track[-1][1:])
    print(f"live tracking error: mean {mean_mm:.1f} mm over {len(errors)} ticks (box moved {moved_mm:.0f} mm)")
    assert moved_mm > 100, "the scenario pushes the box"
    assert mean_mm < 15.0


def test_object_messages_are_complete(main_run):
    _, msg = main_run["recorder"].got["objects"][-1]
    assert [o.name for o in msg.objects] == ["box"]
    assert msg.header.frame_id == "world"
    q = msg.objects[0].pose.orientation
    assert abs(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w - 1.0) < 1e-6
    _, cloud = main_run["recorder"].got["particles"][-1]
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "object_id"]
    assert cloud.point_step == 16 and len(cloud.data) == cloud.width * 16 and cloud.width > 100
    _, tf = main_run["recorder"].got["tf"][-1]
    assert tf.transforms[0].child_frame_id == "box" and tf.transforms[0].header.frame_id == "world"
    # The compressed debug image is a lossless PNG of the raw one.
    _, raw = main_run["recorder"].got["debug"][-1]
    assert raw.header.frame_id == "cam0_color_optical_frame", raw.header.frame_id
    assert (raw.width, raw.height, raw.encoding) == (160, 90, "rgb8") and len(raw.data) == 160 * 90 * 3
    _, compressed = main_run["recorder"].got["debug_compressed"][-1]
    assert "png" in compressed.format and bytes(compressed.data[:8]) == b"\x89PNG\r\n\x1a\n"
    assert max(raw.data) > 50, "the debug render shows the scene"


def test_every_bad_input_is_refused_counted_and_reported(main_run):
    sent = main_run["sent"]
    assert set(sent) == {"wrong_encoding", "wrong_size", "nan_joints", "unknown_joint", "backwards", "future", "malformed", "burst", "stop_cam2"}
    stats, log = main_run["stats"], main_run["log"]
    rejections = stats["rejections"]
    assert rejections.get("bad_image", 0) >= 2, rejections
    assert rejections.get("non_finite", 0) >= 1, rejections
    # The backwards image (5 s behind) is a jump back; the burst (0.2 s behind the newest image)
    # is out of order, each image refused without displacing the newest good one.
    assert rejections.get("jumped_back", 0) >= 1, rejections
    assert rejections.get("out_of_order", 0) >= 1, rejections
    burst = sent["burst"] - 0.2
    refused = [float(m) for m in re.findall(r"camera cam0 image at (\d+\.\d+) s: stamp \S+ s is not after the newest", log)]
    assert any(abs(t - burst) < 0.01 for t in refused), f"no burst image ({burst:.3}) refused as out of order: {refused}"
    backwards = sent["backwards"] - 5.0
    jumped = [float(m) for m in re.findall(r"camera cam0 image at (\d+\.\d+) s: stamp \S+ s is \S+ s behind the newest", log)]
    assert any(abs(t - backwards) < 0.01 for t in jumped), f"the backwards image ({backwards:.3}) was not refused as a jump back: {jumped}"
    assert rejections.get("future_stamp", 0) >= 1, rejections
    assert stats["malformed_messages"] >= 1, stats
    for needle in ["mono8", "CameraInfo says", "non-finite", "mystery_joint", "in the future", "malformed"]:
        assert needle in log, f"no log line mentions '{needle}'"
    inputs = last_diagnostics(main_run)["pegs: inputs"]
    values = {kv.key: kv.value for kv in inputs.values}
    assert level(inputs) == 1, inputs.message
    assert "mystery_joint" in values["unknown_joints"]
    assert int(values["bad_image"]) >= 2 and int(values["future_stamp"]) >= 1


def test_a_camera_that_stops_is_reported_and_tracking_continues(main_run):
    status = last_diagnostics(main_run)
    assert level(status["pegs: camera cam2"]) == 2 and "stopped publishing" in status["pegs: camera cam2"].message
    assert level(status["pegs: camera cam0"]) in (0, 1)
    # The tracked box's own status: tracked, its silhouette agreeing with the images.
    box = status["pegs: object box"]
    values = {kv.key: kv.value for kv in box.values}
    agreement = values["silhouette_agreement"]
    assert level(box) == 0 and float(agreement) > 0.6, (box.message, agreement)
    assert values["off_table"] == "false", values
    # The ages of the images the ticks used are reported, and none is past the limit (70 ms) either
    # way: an image stamped up to the limit ahead of a tick is used too (under load the player's
    # images can run a millisecond ahead of the node's ticks).
    ages = {kv.key: kv.value for kv in status["pegs: camera cam0"].values}
    mean, oldest = float(ages["age_used_ms_mean"]), float(ages["age_used_ms_max"])
    assert int(ages["ticks_used"]) > 0 and -70.0 <= mean <= oldest <= 70.0, ages
    # Poses kept coming after cam2 stopped (checked against the truth in the tracking test).
    player, start = main_run["player"], main_run["start"]
    after = [m for _, m in main_run["recorder"].got["objects"] if player.recording_time(stamp_of(m)) > 3.0]
    assert len(after) > 20


def test_parameters_are_listed_read_and_set(main_run):
    p = main_run["params"]
    assert {"correct.gain", "physics.dt", "node.cameras", "scene.scenario"} <= set(p["names"])
    assert abs(p["gain_before"] - configured_gain(main_run["recording"])) < 1e-6
    assert p["set_gain"].successful, p["set_gain"].reason
    assert abs(p["gain_after"] - 800.0) < 1e-9
    assert not p["set_dt"].successful and "fixed" in p["set_dt"].reason
    assert not p["set_bad_gain"].successful
    assert abs(p["dt_after"] - 1 / 30) < 1e-6
    # Descriptors: what changes live is writable, what builds the world is read-only.
    gain, dt, sim = p["described"]
    assert (gain.name, gain.type, gain.read_only) == ("correct.gain", ParameterType.PARAMETER_DOUBLE, False), gain
    assert gain.description and "next tick" in gain.additional_constraints, gain
    assert dt.read_only and "restart" in dt.additional_constraints, dt
    assert sim.read_only and sim.type == ParameterType.PARAMETER_BOOL, sim
    # The accepted change, and only it, is announced on /parameter_events.
    changed = [(e.node, c.name, c.value.double_value) for e in p["events"] for c in e.changed_parameters]
    assert changed == [("/pegs", "correct.gain", 800.0)], changed
    # The tick thread applies the new gain: diagnostics after the change report it.
    after = [m for t, m in main_run["recorder"].got["diagnostics"] if t > p["set_at"] + 0.2]
    gains = [float(kv.value) for m in after for st in m.status if st.name == "pegs: tracking" for kv in st.values if kv.key == "gain"]
    assert gains and abs(gains[-1] - 800.0) < 1e-6, f"the tracker still corrects with {gains}"


def test_node_runs_without_camera_info_for_one_camera(recording, ros):
    node = rclpy.create_node("pegs_test_missing_info")
    recorder = Recorder(node)
    proc, stats_path = start_node(recording, "missing_info")
    player = Player(node, str(recording / "recording"), skip_topics=("/camera/cam2/color/camera_info",))
    wait_for_discovery(node, player)
    # Twice through: the node waits a few seconds for the missing CameraInfo before it starts.
    for _ in range(2):
        player.cursor = 0
        begin = time.time() + 0.2
        player.begin(begin)
        spin_for(node, RUN_SECONDS + 0.5, player)
    stats = stop_node(proc, stats_path)
    node.destroy_node()
    log = (recording / "missing_info.log").read_text()
    assert "camera cam2: no CameraInfo" in log
    assert recorder.count("objects") > 30, "tracking went on with two cameras"
    assert stats["ticks"] > 30
    # Judged on the last report sent while images flowed (after that cam0 has no fresh image).
    reports = [msg for t, msg in recorder.got["diagnostics"] if t <= begin + RUN_SECONDS]
    status = {s.name: s for s in reports[-1].status}
    assert level(status["pegs: camera cam2"]) == 2 and "no CameraInfo" in status["pegs: camera cam2"].message
    assert level(status["pegs: camera cam0"]) == 0


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def test_large_images_are_not_hoarded_by_the_receive_cache(recording, ros):
    """Each subscription keeps at most its history depth: 60 large depth images (0.9 MB each) sent
    while the node waits for cameras must not stay in memory (RustDDS's default keeps 64 per topic,
    which is how a long run grew by the depth and mask images of every recording loop)."""
    node = rclpy.create_node("pegs_test_cache")
    proc, stats_path = start_node(recording, "cache")
    pub = node.create_publisher(Image, "/camera/cam0/aligned_depth_to_color/image_raw", SENSOR)
    end = time.time() + 20
    while time.time() < end and node.count_subscribers("/camera/cam0/aligned_depth_to_color/image_raw") == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    spin_for(node, 1.0)
    before = rss_mb(proc.pid)
    img = Image(height=360, width=640, encoding="32FC1", step=640 * 4, data=bytes(640 * 360 * 4))
    img.header.frame_id = "cam0_color_optical_frame"
    for _ in range(60):
        pub.publish(set_stamp(img, time.time()))
        spin_for(node, 0.05)
    spin_for(node, 1.0)
    grown = rss_mb(proc.pid) - before
    stop_node(proc, stats_path)
    node.destroy_node()
    assert grown < 20, f"the node kept {grown:.0f} MB of 60 depth images"


def run_to_exit(config: Path, log: Path, timeout: float):
    """Run the node with `config` until it exits by itself; (return code, seconds, output)."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    start = time.time()
    with open(log, "w") as out:
        proc = subprocess.Popen([PEGS, "node", "--config", str(config)], env=env, stdout=out, stderr=subprocess.STDOUT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise AssertionError(f"the node still ran after {timeout} s: {log.read_text()}")
    return proc.returncode, time.time() - start, log.read_text()


def test_a_configuration_that_cannot_work_is_refused_at_start(recording):
    """Nothing to track, a URDF that is not there, no cameras named: each is refused at start
    (non-zero exit within 5 s) with the setting named, not found out in the tick thread later."""
    cases = {
        "nothing_to_track": ("node: {cameras: [cam0]}", "scene.rgbd_objects"),
        "missing_urdf": ("robot: {urdf: no_such.urdf}\n    node: {cameras: [cam0]}\n    scene: {scenario: pushed_box}", "robot.urdf"),
        "no_cameras": ("scene: {scenario: pushed_box}", "node.cameras"),
    }
    for name, (body, setting) in cases.items():
        config = recording / f"{name}.yaml"
        config.write_text(f"pegs:\n  ros__parameters:\n    {body}\n")
        code, seconds, out = run_to_exit(config, recording / f"{name}.log", timeout=20)
        assert code != 0 and seconds < 5, f"{name}: exit {code} after {seconds:.1f} s: {out}"
        assert setting in out, f"{name}: '{setting}' not named in: {out}"


def test_an_error_in_the_tick_thread_stops_the_node_at_once(recording, ros):
    """A URDF that exists but cannot be read fails when the scene is built from the first frames,
    in the tick thread: the node exits non-zero with the reason as soon as that happens, instead of
    running on silently until a signal."""
    (recording / "broken.urdf").write_text("<robot name='arm'><link name='a'>")
    config = recording / "tick_error.yaml"
    config.write_text(
        "pegs:\n  ros__parameters:\n    robot: {urdf: broken.urdf}\n    node: {cameras: [cam0, cam1, cam2]}\n"
        "    scene:\n      rgbd_objects: [{name: box, label: 1, mass: 0.2, particle_radius: 0.005}]\n")
    node = rclpy.create_node("pegs_test_tick_error")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    log = recording / "tick_error.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([PEGS, "node", "--config", str(config)], env=env, stdout=out, stderr=subprocess.STDOUT)
        player = Player(node, str(recording / "recording"))
        end = time.time() + 20
        while time.time() < end and any(node.count_subscribers(t) == 0 for t in player.publishers):
            rclpy.spin_once(node, timeout_sec=0.05)
        player.begin(time.time() + 0.2)
        started = time.time()
        while proc.poll() is None and time.time() - started < 15:
            player.publish_due(time.time())
            rclpy.spin_once(node, timeout_sec=0.003)
        running = proc.poll() is None
        if running:
            proc.kill()
        proc.wait()
    node.destroy_node()
    text = log.read_text()
    assert not running, f"the node kept running after its tick thread failed: {text}"
    assert proc.returncode != 0, text
    assert "malformed URDF" in text and "the tick thread ended" in text, text


def test_a_camera_that_starts_late_joins_the_tracking(recording, ros):
    """cam2 (CameraInfo and images) starts 7 s after the others: the node starts with cam0 and
    cam1 after its wait (node.camera_wait, 5 s), then cam2 joins at the next tick once its
    CameraInfo arrives, its images are used and its diagnostics clear."""
    node = rclpy.create_node("pegs_test_late_camera")
    recorder = Recorder(node)
    proc, stats_path = start_node(recording, "late_camera")
    player = Player(node, str(recording / "recording"))
    wait_for_discovery(node, player)
    player.paused_topics.add("/camera/cam2/")
    started = time.time()
    for _ in range(3):
        player.cursor = 0
        begin = time.time() + 0.2
        player.begin(begin)

        def unpause(now):
            if now - started > 7.0:
                player.paused_topics.discard("/camera/cam2/")

        spin_for(node, RUN_SECONDS + 0.5, player, each=unpause)
    # The last loop's images stop at begin + RUN_SECONDS: a report after that finds every camera
    # without a fresh image, which is what it should say, so judge cam2 on the last report sent
    # while images still flowed.
    playing_until = begin + RUN_SECONDS
    stats = stop_node(proc, stats_path)
    node.destroy_node()
    log = (recording / "late_camera.log").read_text()
    assert "camera cam2: no CameraInfo" in log, log
    assert "camera cam2: ready at" in log and "joins the tracking" in log, log
    assert stats["images_accepted"].get("cam2", 0) > 10, stats["images_accepted"]
    reports = [msg for t, msg in recorder.got["diagnostics"] if t <= playing_until]
    status = {s.name: s for s in reports[-1].status}
    assert level(status["pegs: camera cam2"]) == 0, status["pegs: camera cam2"].message


def test_fr3_joint_names_drive_the_panda_urdf_with_a_prefix_parameter(recording, ros):
    """franka_ros2 on Jazzy publishes fr3_joint*, the URDF names panda_joint*. Without a mapping no
    joint matches and after 2 s of tracking /diagnostics says so as an ERROR naming the setting;
    with robot.joint_prefix_received:=fr3_ and robot.joint_prefix_urdf:=panda_ the joints drive the
    robot and nothing is unknown."""
    from rclpy.serialization import deserialize_message, serialize_message
    mapping = ("-p", "robot.joint_prefix_received:=fr3_", "-p", "robot.joint_prefix_urdf:=panda_")
    for name, extra, expected in [("fr3_unmapped", (), 2), ("fr3_mapped", mapping, 0)]:
        node = rclpy.create_node(f"pegs_test_{name}")
        recorder = Recorder(node)
        proc, stats_path = start_node(recording, name, extra)
        player = Player(node, str(recording / "recording"))
        for k, (t, topic, type_name, cdr) in enumerate(player.messages):
            if topic == "/joint_states":
                js = deserialize_message(cdr, JointState)
                js.name = [n.replace("panda_", "fr3_", 1) for n in js.name]
                player.messages[k] = (t, topic, type_name, serialize_message(js))
        wait_for_discovery(node, player)
        player.begin(time.time() + 0.2)
        spin_for(node, RUN_SECONDS + 0.5, player)

        def robot_status():
            reports = recorder.got.get("diagnostics", [])
            status = {s.name: s for s in reports[-1][1].status} if reports else {}
            return status, status.get("pegs: robot")

        # A slow machine may start tracking late: the deadline counts tracked seconds, so wait (the
        # node keeps ticking on its wall clock) until the robot is no longer waiting, 10 s at most.
        end = time.time() + 10.0
        while time.time() < end and (robot_status()[1] is None or robot_status()[1].message == "waiting for joint states"):
            spin_for(node, 0.2)
        stats = stop_node(proc, stats_path)
        node.destroy_node()
        status, robot = robot_status()
        assert robot is not None, f"{name}: no robot status in {list(status)}"
        assert level(robot) == expected, f"{name}: {robot.message} (ticks {stats.get('ticks')}, skipped {stats.get('skipped_ticks')})"
        inputs = {v.key: v.value for v in status["pegs: inputs"].values}
        if expected:
            assert "robot.joint_prefix_received" in robot.message and "fr3_joint1" in robot.message, robot.message
        else:
            assert inputs["unknown_joints"] == "", inputs


def run_with_garbage_on_depth(recording, log_name, extra=(), depth_frames=0):
    """Play the recording to the node (`extra` ROS args); once tracking runs, send `depth_frames`
    valid depth images of cam0 (32FC1, 0.8 m, stamped now) and garbage on cam0's depth and mask
    topics and on cam1's CameraInfo (still subscribed). The node's log, the last `pegs: inputs`
    diagnostic values and the count of object messages."""
    node = rclpy.create_node(f"pegs_test_{log_name}")
    recorder = Recorder(node)
    proc, stats_path = start_node(recording, log_name, extra)
    player = Player(node, str(recording / "recording"))
    depth = "/camera/cam0/aligned_depth_to_color/image_raw"
    mask = "/camera/cam0/mask/image_raw"
    info = "/camera/cam1/color/camera_info"
    wait_for_discovery(node, player)
    player.begin(time.time() + 0.2)
    spin_for(node, 3.0, player)
    # A slow machine may start tracking late: the depth must come once it runs.
    end = time.time() + 10.0
    while time.time() < end and recorder.count("objects") == 0:
        spin_for(node, 0.2, player)
    depth_pub = node.create_publisher(Image, depth, SENSOR)
    mask_pub = node.create_publisher(Image, mask, SENSOR)
    spin_for(node, 1.0, player)
    metres = struct.pack("<f", 0.8) * (160 * 90)
    for _ in range(depth_frames):
        img = Image(height=90, width=160, encoding="32FC1", is_bigendian=0, step=160 * 4, data=metres)
        img.header.frame_id = "cam0_color_optical_frame"
        depth_pub.publish(set_stamp(img, time.time()))
        spin_for(node, 0.05, player)
    for _ in range(10):
        depth_pub.publish(b"\x00\x01\x00\x00\x07")
        mask_pub.publish(b"\x00\x01\x00\x00\x07")
        player.publishers[info].publish(b"\x00\x01\x00\x00\x07")
        spin_for(node, 0.05, player)
    spin_for(node, 1.5, player)
    stop_node(proc, stats_path)
    node.destroy_node()
    reports = recorder.got.get("diagnostics", [])
    inputs = {}
    for _, m in reports:
        for st in m.status:
            if st.name == "pegs: inputs" and st.values:
                inputs = {v.key: v.value for v in st.values}
    return (recording / f"{log_name}.log").read_text(), inputs, recorder.count("objects")


def test_depth_reaches_tracking_and_masks_end_once_tracking_runs(recording, ros):
    """With depth in the pose search (`correct.pose_search_depth`, on by default) the depth
    subscription stays once tracking runs: a valid depth image of cam0 reaches the tracker (the
    inputs diagnostic names cam0 among `depth_cameras`) and garbage on it is counted as
    malformed, as on CameraInfo. Masks are read once, to initialise: their subscription ends and
    garbage sent on it afterwards is never seen."""
    mask = "/camera/cam0/mask/image_raw"
    depth = "/camera/cam0/aligned_depth_to_color/image_raw"
    log, inputs, objects = run_with_garbage_on_depth(recording, "depth_on", depth_frames=5)
    assert objects > 5, "tracking ran"
    assert "cam0" in inputs.get("depth_cameras", "").split(","), inputs
    assert f"{mask}: no longer needed; unsubscribed" in log, log
    assert f"{mask}: malformed message" not in log, "the mask subscription still receives"
    assert f"{depth}: malformed message" in log, "the depth subscription no longer receives"
    assert f"{depth}: no longer needed" not in log, log


def test_without_depth_in_tracking_its_subscription_ends_once_tracking_runs(recording, ros):
    """With `correct.pose_search_depth` 0 depth is read once, to initialise, like the masks: once
    tracking runs the subscription is dropped, so the node no longer receives or deserialises
    it. Garbage sent on the depth topic afterwards is never seen, while the same garbage on
    CameraInfo (still subscribed) is counted as malformed."""
    depth = "/camera/cam0/aligned_depth_to_color/image_raw"
    info = "/camera/cam1/color/camera_info"
    log, inputs, objects = run_with_garbage_on_depth(
        recording, "depth_off", ["-p", "correct.pose_search_depth:=0.0"], depth_frames=5)
    assert objects > 5, "tracking ran"
    assert f"{depth}: no longer needed; unsubscribed" in log, log
    assert f"{info}: malformed message" in log, "garbage reaches a subscribed topic"
    assert f"{depth}: malformed message" not in log, "the depth subscription still receives"
    assert inputs.get("depth_cameras") == "", inputs


def test_diagnostics_say_what_the_node_waits_for_before_tracking(recording, ros):
    """From start-up, before any camera is ready, /diagnostics says what the node waits for:
    each camera's CameraInfo and first image by name; once CameraInfo but no tf arrives for a
    camera, the tf chain it needs."""
    node = rclpy.create_node("pegs_test_waiting")
    recorder = Recorder(node)
    proc, stats_path = start_node(recording, "waiting")
    player = Player(node, str(recording / "recording"))
    wait_for_discovery(node, player)
    spin_for(node, 2.5)
    first = [m for _, m in recorder.got.get("diagnostics", [])]
    # Now CameraInfo of every camera, but no /tf_static: the tf chains are what is missing.
    player.tf_static = None
    player.paused_topics.update({"/camera/cam0/color/image_raw", "/camera/cam1/color/image_raw", "/camera/cam2/color/image_raw"})
    player.begin(time.time() + 0.1)
    spin_for(node, 2.5, player)
    later = [m for _, m in recorder.got.get("diagnostics", [])]
    stop_node(proc, stats_path)
    node.destroy_node()
    assert first, "no /diagnostics before tracking"
    start = {s.name: s for s in first[0].status}["pegs: start-up"]
    assert level(start) == 1, start
    for part in ["cam0 CameraInfo", "cam2 CameraInfo"]:
        assert part in start.message, start.message
    last = {s.name: s for s in later[-1].status}["pegs: start-up"]
    assert "cam1 tf world -> cam1_color_optical_frame" in last.message, last.message
    assert "CameraInfo" not in last.message, last.message


def test_log_lines_reach_rosout(recording, ros):
    """What the node logs reaches /rosout under its name, so `ros2 topic echo /rosout` and
    rqt_console show it: the start-up line and the tracking line."""
    from rcl_interfaces.msg import Log
    node = rclpy.create_node("pegs_test_rosout")
    lines = []
    node.create_subscription(Log, "/rosout", lambda m: lines.append(m), 100)
    proc, stats_path = start_node(recording, "rosout")
    player = Player(node, str(recording / "recording"))
    wait_for_discovery(node, player)
    player.begin(time.time() + 0.2)
    spin_for(node, 3.0, player)
    stop_node(proc, stats_path)
    node.destroy_node()
    ours = [m for m in lines if m.name == "pegs"]
    assert any("tracking 1 object(s)" in m.msg for m in ours), [m.msg for m in ours]


def test_topic_remaps_rename_what_the_node_publishes_and_reads(recording, ros):
    """`-r from:=to` as ROS users write it: the poses come out on the remapped name, and a camera
    whose image topic is remapped away from what is played gets no images (reported as such)."""
    node = rclpy.create_node("pegs_test_remap")
    recorder = Recorder(node)
    got = []
    node.create_subscription(PoseArray, "/tracked_poses", lambda m: got.append(m), 50)
    extra = ("-r", "/pegs/poses:=/tracked_poses", "-r", "/camera/cam2/color/image_raw:=/elsewhere/image")
    proc, stats_path = start_node(recording, "remap", extra)
    player = Player(node, str(recording / "recording"))
    end = time.time() + 20
    while time.time() < end and (node.count_publishers("/tracked_poses") == 0 or node.count_subscribers("/camera/cam0/color/image_raw") == 0):
        rclpy.spin_once(node, timeout_sec=0.05)
    spin_for(node, 0.5)
    player.begin(time.time() + 0.2)
    spin_for(node, RUN_SECONDS, player)
    stop_node(proc, stats_path)
    node.destroy_node()
    assert len(got) >= 5, f"{len(got)} poses on /tracked_poses"
    assert recorder.count("poses") == 0, "nothing on the original name"
    status = {s.name: s for s in recorder.got["diagnostics"][-1][1].status}
    assert level(status["pegs: camera cam2"]) == 2, status["pegs: camera cam2"].message


def test_simulated_time_from_clock_drives_the_ticks(recording, ros):
    """With use_sim_time the node's clock is /clock, as `ros2 bag play --clock` publishes it: it
    waits for /clock (and says so), ticks at 30 Hz of simulated time (here running at half speed,
    far from the wall clock, with a one-second pause), judges and stamps on it, and when the clock
    goes back (a bag played again) it restarts its world's clock there."""
    from rosgraph_msgs.msg import Clock
    node = rclpy.create_node("pegs_test_sim_time")
    recorder = Recorder(node)
    clock_pub = node.create_publisher(Clock, "/clock", 10)
    proc, stats_path = start_node(recording, "sim_time", ("-p", "use_sim_time:=true"))
    player = Player(node, str(recording / "recording"))
    wait_for_discovery(node, player)
    spin_for(node, 1.5)
    waiting = [m for _, m in recorder.got.get("diagnostics", [])]
    sim0, rate, played = 1000.0, 0.5, 3.0  # simulated start, its speed, seconds of recording
    wall0 = time.time() + 0.3
    pause_at, pause_s = 1.5, 1.0  # simulated seconds after sim0; wall seconds

    def sim(now):
        if now < wall0:
            return sim0
        s = rate * (now - wall0)
        if s > pause_at:
            s = max(pause_at, s - rate * pause_s)
        return sim0 + s

    def tick_clock(now):
        t = sim(now)
        clock_pub.publish(set_stamp_clock(Clock(), t))
        player.publish_due(t)

    player.begin(sim0 + 0.2)
    end_wall = wall0 + played / rate + pause_s
    spin_for(node, end_wall - time.time(), None, tick_clock)
    played_until = sim(time.time())
    received = list(recorder.got.get("objects", []))
    # The clock goes back 2 s (a bag replayed) and runs on at full speed for 1.5 s.
    back = played_until - 2.0
    wall_back = time.time()
    spin_for(node, 1.5, None, lambda now: (clock_pub.publish(set_stamp_clock(Clock(), back + now - wall_back))))
    stop_node(proc, stats_path)
    node.destroy_node()
    log = (recording / "sim_time.log").read_text()

    assert waiting and any("/clock (use_sim_time)" in s.message for m in waiting for s in m.status), "start-up diagnostics name /clock"
    stamps = sorted(stamp_of(m) for _, m in received)
    assert stamps and sim0 <= stamps[0] and stamps[-1] <= played_until + 0.05, f"stamps {stamps[:2]}..{stamps[-2:]} are not simulated time"
    dt = 1.0 / 30.0
    span = stamps[-1] - stamps[0]
    assert len(stamps) >= 0.8 * span / dt and len(stamps) <= span / dt + 2, f"{len(stamps)} ticks over {span:.2f} simulated s"
    # While the clock stood still (wall seconds 3.0 .. 4.0 after wall0) no tick ran past it.
    paused = [stamp_of(m) for w, m in received if wall0 + pause_at / rate + 0.2 <= w <= wall0 + pause_at / rate + pause_s]
    assert all(s <= sim0 + pause_at + 2 * dt for s in paused), f"ticks while /clock stood still: {paused}"
    # Tracking on simulated stamps: the box follows the ground truth.
    errors = box_errors(received, player, recording, played)
    assert len(errors) >= 10 and sum(errors) / len(errors) < 0.015, f"{len(errors)} ticks, mean {1e3 * sum(errors) / max(len(errors), 1):.1f} mm"
    assert "the clock went back" in log, log
    after = [stamp_of(m) for w, m in recorder.got["objects"] if w > wall_back + 0.3]
    assert after and all(back - 0.1 <= s <= back + 1.6 for s in after), f"after the jump: {after[:3]}..{after[-3:]}"


def set_stamp_clock(msg, t: float):
    msg.clock.sec = int(t)
    msg.clock.nanosec = int(round((t - int(t)) * 1e9)) % 1_000_000_000
    return msg


def test_the_robot_comes_from_robot_description_and_stands_where_tf_puts_its_base(recording, ros):
    """robot_state_publisher offers the URDF on /robot_description (transient local) and the rig's
    calibration puts the robot's root link in the tf tree: with robot.description_topic set and no
    URDF file, the node waits for the description, and with robot.base_frame named for its tf
    (start-up diagnostics name both), builds the arm from it, and places its base from tf
    world -> panda_link0 rather than from the configured base_position (0.5 m off here); the
    pushed box is then tracked as with the true base."""
    from geometry_msgs.msg import TransformStamped
    from std_msgs.msg import String
    config = recording / "description.yaml"
    config.write_text(
        "pegs:\n  ros__parameters:\n    robot: {description_topic: /robot_description, base_frame: panda_link0, base_position: [0.0, 0.0, 0.5]}\n"
        "    node: {cameras: [cam0, cam1, cam2], camera_wait: 30.0}\n"
        "    scene:\n      rgbd_objects: [{name: box, label: 1, mass: 0.36, particle_radius: 0.005}]\n"
        "      ground_from_depth: true\n")
    node = rclpy.create_node("pegs_test_description")
    recorder = Recorder(node)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    log = recording / "description.log"
    stats_path = recording / "description.stats.json"
    with open(log, "w") as out:
        proc = subprocess.Popen([PEGS, "node", "--config", str(config), "--stats", str(stats_path)], env=env, stdout=out, stderr=subprocess.STDOUT)
    player = Player(node, str(recording / "recording"))
    # Publishers made now, so that they are discovered before they publish.
    description = node.create_publisher(String, "/robot_description", LATCHED)
    base_pub = node.create_publisher(TFMessage, "/tf_static", LATCHED)
    wait_for_discovery(node, player)
    player.begin(time.time() + 0.2)
    spin_for(node, 2.0, player)
    waiting = [m for _, m in recorder.got.get("diagnostics", [])]
    assert recorder.count("objects") == 0, "tracking started without the robot's description"
    description.publish(String(data=(ROOT / "urdf" / "panda_pusher.urdf").read_text()))
    spin_for(node, 1.5)
    waiting += [m for _, m in recorder.got.get("diagnostics", [])][len(waiting):]
    assert recorder.count("objects") == 0, "tracking started without the named base frame's tf"
    # The recording again from its start; the base's tf once its first frames are in.
    player.cursor = 0
    player.begin(time.time() + 0.2)
    spin_for(node, 0.8, player)
    base = TransformStamped()
    base.header.frame_id, base.child_frame_id = "world", "panda_link0"
    base.transform.rotation.w = 1.0
    base_pub.publish(TFMessage(transforms=[base]))
    spin_for(node, RUN_SECONDS - 0.3, player)
    stop_node(proc, stats_path)
    node.destroy_node()
    text = log.read_text()
    assert any("robot_description on /robot_description" in s.message for m in waiting for s in m.status), "start-up diagnostics name the description"
    assert any("tf world -> panda_link0 (robot base)" in s.message for m in waiting for s in m.status), "start-up diagnostics name the base tf"
    assert "robot base from tf world -> panda_link0: position [0.0, 0.0, 0.0]" in text, text
    robot = [s for _, m in recorder.got["diagnostics"] for s in m.status if s.name == "pegs: robot"]
    assert robot and level(robot[-1]) == 0, robot[-1].message if robot else "no robot status: tracking never ran"
    errors = box_errors(recorder.got["objects"], player, recording)
    mean_mm = 1e3 * sum(errors) / max(len(errors), 1)
    print(f"robot from /robot_description, base from tf: box tracked at {mean_mm:.1f} mm mean over {len(errors)} ticks")
    first = [round(1e3 * e, 1) for e in errors[:6]]
    assert len(errors) >= 8 and mean_mm < 15.0, f"{len(errors)} ticks, {mean_mm:.1f} mm (first, mm: {first}); node log:\n{text[-3000:]}"


def test_a_namespaced_node_resolves_its_topics_and_takes_its_sections_of_a_shared_params_file(recording, ros):
    """Launched as /rig/pegs with a parameter file shared by the rig's nodes: relative topics
    resolve under the namespace (joint_states -> /rig/joint_states, outputs under /rig/pegs),
    absolute ones (cameras, /tf_static, /diagnostics) stay; the node applies `/**` and its own
    `/rig/pegs` section in file order, ignores the other nodes' sections and their keys under
    `/**`, and serves the result as parameters."""
    params = recording / "rig_params.yaml"
    params.write_text(
        "/**:\n  ros__parameters:\n    use_sim_time: false\n    serial_no: '0123'\n    correct:\n      gain: 900.0\n"
        "/camera/cam0:\n  ros__parameters:\n    rgb_camera.color_profile: 640x360x30\n    correct:\n      gain: 5.0\n"
        "/rig/pegs:\n  ros__parameters:\n    correct:\n      damping: 33.0\n"
        "/other/pegs:\n  ros__parameters:\n    correct:\n      damping: 1.0\n")
    node = rclpy.create_node("pegs_test_namespace")
    got = []
    node.create_subscription(TrackedObjectArray, "/rig/pegs/objects", lambda m: got.append(m), 50)
    js_pub = node.create_publisher(JointState, "/rig/joint_states", RELIABLE)
    proc, stats_path = start_node(recording, "namespace", ("-r", "__ns:=/rig", "--params-file", str(params)))
    player = Player(node, str(recording / "recording"))
    end = time.time() + 20
    while time.time() < end and (node.count_publishers("/rig/pegs/objects") == 0 or node.count_subscribers("/rig/joint_states") == 0):
        rclpy.spin_once(node, timeout_sec=0.05)
    subscribed_root = node.count_subscribers("/joint_states")
    # The recording's joint states go to the namespaced topic.
    for k, (t, topic, type_name, cdr) in enumerate(player.messages):
        if topic == "/joint_states":
            player.messages[k] = (t, "/rig/joint_states", type_name, cdr)
    player.publishers["/rig/joint_states"] = js_pub
    spin_for(node, 0.5)
    player.begin(time.time() + 0.2)
    spin_for(node, 3.0, player)
    get = node.create_client(GetParameters, "/rig/pegs/get_parameters")
    values = call(node, get, GetParameters.Request(names=["correct.gain", "correct.damping", "use_sim_time"])).values
    stop_node(proc, stats_path)
    node.destroy_node()
    log = (recording / "namespace.log").read_text()
    assert len(got) >= 5, f"{len(got)} messages on /rig/pegs/objects"
    assert subscribed_root == 0, "the node reads /joint_states outside its namespace"
    assert [values[0].double_value, values[1].double_value, values[2].bool_value] == [900.0, 33.0, False], values
    assert "'serial_no' under '/**' is not a pegs parameter; ignored" in log, log


def test_colcon_installs_the_node_its_configuration_urdfs_and_messages():
    """`colcon build` of this repository (colcon-ros-cargo for pegs, ament_cmake for pegs_msgs in
    msg/) installs what a ROS user runs: the executable where `ros2 run pegs pegs` looks, the
    configurations and URDFs in share/pegs (the rig configuration finds its URDF there), and the
    pegs_msgs Python messages these tests import."""
    import pegs_msgs
    install = Path(os.environ["PEGS_INSTALL"]).resolve()
    assert Path(pegs_msgs.__file__).resolve().is_relative_to(install / "pegs_msgs"), pegs_msgs.__file__
    assert Path(PEGS).resolve() == install / "pegs" / "lib" / "pegs" / "pegs"
    assert (install / "pegs" / "share" / "ament_index" / "resource_index" / "packages" / "pegs").exists()
    share = install / "pegs" / "share" / "pegs"
    for f in ["package.xml", "config/pegs.yaml", "config/franka_3xd455.yaml", "urdf/panda_pusher.urdf"]:
        assert (share / f).is_file(), f
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    run = subprocess.run([PEGS, "node", "--config", str(share / "config" / "franka_3xd455.yaml"), "--duration", "0.5"],
                         env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    (share / "urdf" / "panda_pusher.urdf").rename(share / "urdf" / "moved.urdf")
    try:
        run = subprocess.run([PEGS, "node", "--config", str(share / "config" / "franka_3xd455.yaml"), "--duration", "0.5"],
                             env=env, capture_output=True, text=True, timeout=60)
    finally:
        (share / "urdf" / "moved.urdf").rename(share / "urdf" / "panda_pusher.urdf")
    assert run.returncode != 0 and "panda_pusher.urdf does not exist" in run.stdout + run.stderr, run.stdout + run.stderr


def qmul(a, b):
    """Hamilton product of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def qrotate(q, v):
    x, y, z, _ = qmul(qmul(q, (*v, 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def test_cameras_are_posed_through_a_two_hop_tf_chain(recording, ros):
    """As realsense2_camera publishes it: the calibration gives world -> camN_link and the driver
    camN_link -> camN_color_optical_frame. The node composes the chain, uses every camera, and
    tracks the pushed box as well as with the direct world -> optical edge."""
    from geometry_msgs.msg import TransformStamped
    node = rclpy.create_node("pegs_test_tf_chain")
    recorder = Recorder(node)
    proc, stats_path = start_node(recording, "tf_chain")
    player = Player(node, str(recording / "recording"))
    link_q = (0.0, 0.0, math.sin(math.radians(15)), math.cos(math.radians(15)))  # 30 deg about z
    link_t = (0.1, -0.05, 0.2)
    chain = []
    for t in player.tf_static.transforms:
        optical = t.child_frame_id
        link = optical.replace("_color_optical_frame", "_link")
        assert link != optical, optical
        first = TransformStamped()
        first.header.frame_id, first.child_frame_id = t.header.frame_id, link
        first.transform.translation.x, first.transform.translation.y, first.transform.translation.z = link_t
        (first.transform.rotation.x, first.transform.rotation.y, first.transform.rotation.z, first.transform.rotation.w) = link_q
        # link -> optical = (world -> link)^-1 (world -> optical)
        inv = (-link_q[0], -link_q[1], -link_q[2], link_q[3])
        r = t.transform.rotation
        q = qmul(inv, (r.x, r.y, r.z, r.w))
        d = t.transform.translation
        p = qrotate(inv, (d.x - link_t[0], d.y - link_t[1], d.z - link_t[2]))
        second = TransformStamped()
        second.header.frame_id, second.child_frame_id = link, optical
        second.transform.translation.x, second.transform.translation.y, second.transform.translation.z = p
        (second.transform.rotation.x, second.transform.rotation.y, second.transform.rotation.z, second.transform.rotation.w) = q
        chain += [first, second]
    player.tf_static = TFMessage(transforms=chain)
    wait_for_discovery(node, player)
    player.begin(time.time() + 0.2)
    spin_for(node, RUN_SECONDS + 0.5, player)
    stop_node(proc, stats_path)
    node.destroy_node()
    log = (recording / "tf_chain.log").read_text()
    assert "tracking 1 object(s) with 3 camera(s)" in log, log
    errors = box_errors(recorder.got["objects"], player, recording)
    mean_mm = 1e3 * sum(errors) / max(len(errors), 1)
    print(f"cameras through world -> link -> optical: box tracked at {mean_mm:.1f} mm mean over {len(errors)} ticks")
    assert len(errors) >= 8 and mean_mm < 15.0, f"{len(errors)} ticks, {mean_mm:.1f} mm"

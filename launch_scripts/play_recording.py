#!/usr/bin/env python3
"""Play a pegs recording (MCAP) into ROS 2 in real time, as a camera rig and robot would.

Every header is restamped to the wall clock (recording time + the moment playback started), so a
node that tracks on the wall clock sees fresh data. Images, CameraInfo and JointState go out as
recorded bytes (only the stamp is patched); /tf_static is published once, latched.

    play_recording.py RECORDING (a pegs recording directory or an .mcap file) [--loop] [--rate 1.0] [--skip-topic T ...]

Importable: the tests drive `Player` tick by tick and inject faults between ticks.
"""
import argparse
import struct
import time
from pathlib import Path

import rclpy
from mcap.reader import make_reader
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, Image, JointState
from tf2_msgs.msg import TFMessage

TYPES = {"sensor_msgs/msg/Image": Image, "sensor_msgs/msg/CameraInfo": CameraInfo, "sensor_msgs/msg/JointState": JointState}
SENSOR = QoSProfile(depth=2, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def restamped(cdr: bytes, stamp: float) -> bytes:
    """CDR bytes of a message whose first field is a std_msgs/Header, with the stamp replaced."""
    sec = int(stamp)
    return cdr[:4] + struct.pack("<iI", sec, int(round((stamp - sec) * 1e9)) % 1_000_000_000) + cdr[12:]


def qos_for(topic: str) -> QoSProfile:
    return RELIABLE if topic.endswith("joint_states") else SENSOR


class Player:
    def __init__(self, node, path: str, skip_topics=()):
        self.node = node
        self.messages = []  # (recording time, topic, type name, cdr)
        self.tf_static = None
        # A rosbag2 directory (pegs's recordings) or a lone MCAP file.
        files = sorted(Path(path).glob("*.mcap")) if Path(path).is_dir() else [Path(path)]
        for file in files:
            with open(file, "rb") as f:
                for schema, channel, message in make_reader(f).iter_messages():
                    if channel.topic == "/tf_static":
                        self.tf_static = deserialize_message(message.data, TFMessage)
                    elif schema.name in TYPES and channel.topic not in skip_topics:
                        self.messages.append((message.log_time * 1e-9, channel.topic, schema.name, bytes(message.data)))
        self.messages.sort(key=lambda m: m[0])
        self.t0 = self.messages[0][0]
        self.duration = self.messages[-1][0] - self.t0
        self.publishers = {}
        for _, topic, type_name, _ in self.messages:
            if topic not in self.publishers:
                self.publishers[topic] = node.create_publisher(TYPES[type_name], topic, qos_for(topic))
        self.tf_publisher = node.create_publisher(TFMessage, "/tf_static", LATCHED)
        self.cursor = 0
        self.start = None
        self.paused_topics = set()

    def begin(self, start: float):
        """Start playback: recording time t0 plays at wall time `start`."""
        self.start = start
        if self.tf_static is not None:
            self.tf_publisher.publish(self.tf_static)

    def wall_time(self, t: float) -> float:
        return self.start + (t - self.t0)

    def recording_time(self, stamp: float) -> float:
        return stamp - self.start + self.t0

    def publish_due(self, now: float) -> int:
        """Publish every message whose time has come; returns how many went out."""
        n = 0
        while self.cursor < len(self.messages) and self.wall_time(self.messages[self.cursor][0]) <= now:
            t, topic, _, cdr = self.messages[self.cursor]
            self.cursor += 1
            if any(topic.startswith(p) for p in self.paused_topics):
                continue
            self.publishers[topic].publish(restamped(cdr, self.wall_time(t)))
            n += 1
        return n

    def done(self) -> bool:
        return self.cursor >= len(self.messages)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--loop", action="store_true")
    parser.add_argument("--skip-topic", action="append", default=[])
    args = parser.parse_args()
    rclpy.init()
    node = rclpy.create_node("pegs_player")
    player = Player(node, args.recording, args.skip_topic)
    print(f"playing {len(player.messages)} messages over {player.duration:.1f} s", flush=True)
    try:
        while True:
            player.begin(time.time() + 0.5)
            player.cursor = 0
            while not player.done():
                player.publish_due(time.time())
                time.sleep(0.002)
            if not args.loop:
                break
    except KeyboardInterrupt:
        pass
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()

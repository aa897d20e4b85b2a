"""Publisher and subscriber processes for the `ros2 bag` round-trip tests.

``publish``: a latched StudLayout right away (before any recorder exists), then, once every topic has
``--subscribers`` matched subscriptions, strings and 16UC1 images on a fixed period and a second layout
half way; writes what it sent (topic, digest of the content, header stamp) to ``--out``, then stays up
until SIGINT.
``listen``: subscribes (reliable; transient local for the layout) and writes what it received, with
monotonic receive times, to ``--out`` once ``--expect`` messages arrived or ``--timeout`` passed, then
stays up until SIGINT.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import signal
import sys
import time

import numpy as np
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Image
from std_msgs.msg import String
from stud_welding_msgs.msg import Stud, StudLayout

STRING_TOPIC, IMAGE_TOPIC, LAYOUT_TOPIC = "/bag_test/text", "/bag_test/depth", "/drawing/layout"
TYPES = {STRING_TOPIC: String, IMAGE_TOPIC: Image, LAYOUT_TOPIC: StudLayout}
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def qos_for(topic: str) -> QoSProfile:
    return LATCHED if topic == LAYOUT_TOPIC else RELIABLE


def stamp_of(msg) -> list[int]:
    if hasattr(msg, "header"):
        return [msg.header.stamp.sec, msg.header.stamp.nanosec]
    return [int(msg.data.split()[1]), 0]


def content_digest(msg) -> str:
    """sha256 of a message's field values. Not of its CDR bytes: serialisers leave alignment padding
    uninitialised, so equal messages can serialise to different bytes."""
    if isinstance(msg, Image):
        h = hashlib.sha256(repr((msg.header, msg.height, msg.width, msg.encoding, msg.is_bigendian,
                                 msg.step)).encode())
        h.update(bytes(msg.data))
        return h.hexdigest()
    return hashlib.sha256(repr(msg).encode()).hexdigest()


def layout(i: int) -> StudLayout:
    msg = StudLayout(source_file=f"/tmp/drawing_{i}.dxf", source_units="mm",
                     studs=[Stud(id=f"S{k:04d}", x=0.01 * k, y=-0.02 * i, diameter=0.016, layer="STUDS")
                            for k in range(50)])
    msg.header.frame_id = "drawing"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000 + i, 123_456_789
    return msg


def image(i: int, width: int, height: int) -> Image:
    rng = np.random.default_rng(i)
    depth = (800 + 50 * rng.standard_normal((height, width))).astype("<u2")  # noisy: compresses like real depth
    msg = Image(height=height, width=width, encoding="16UC1", is_bigendian=0, step=2 * width, data=depth.tobytes())
    msg.header.frame_id = "camera_color_optical_frame"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_100 + i, 1000 * i
    return msg


def publish(args) -> int:
    node = rclpy.create_node("bag_test_publisher")
    used = {STRING_TOPIC: args.strings > 0, IMAGE_TOPIC: args.images > 0, LAYOUT_TOPIC: True}
    pubs = {t: node.create_publisher(cls, t, qos_for(t)) for t, cls in TYPES.items() if used[t]}
    sent: list[dict] = []

    def send(topic: str, msg) -> None:
        pubs[topic].publish(msg)
        sent.append({"topic": topic, "sha": content_digest(msg), "stamp": stamp_of(msg), "t": time.monotonic()})

    width, height = (int(v) for v in args.image_size.split("x"))
    send(LAYOUT_TOPIC, layout(0))  # latched: the recorder subscribes later
    print("publisher up", flush=True)
    deadline = time.monotonic() + args.timeout
    while any(p.get_subscription_count() < args.subscribers for p in pubs.values()):
        if time.monotonic() > deadline:
            print("no subscribers", flush=True)
            return 1
        time.sleep(0.02)
    images = [image(i, width, height) for i in range(args.images)]  # built before timing starts
    start = time.monotonic()
    for tick in range(max(args.strings, args.images * args.image_every)):
        while time.monotonic() < start + tick * args.period:
            time.sleep(0.001)
        if tick < args.strings:
            send(STRING_TOPIC, String(data=f"message {tick}"))
        if tick % args.image_every == 0 and tick // args.image_every < args.images:
            send(IMAGE_TOPIC, images[tick // args.image_every])
        if tick == args.strings // 2:
            send(LAYOUT_TOPIC, layout(1))
    for p in pubs.values():
        p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    with open(args.out, "w") as f:
        json.dump(sent, f)
    print(f"published {len(sent)}", flush=True)
    wait_for_sigint()
    return 0


def wait_for_sigint() -> None:
    stop: list[int] = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    while not stop:
        time.sleep(0.05)


def listen(args) -> int:
    node = rclpy.create_node("bag_test_listener")
    received: list[dict] = []

    def on_message(topic: str, data: bytes) -> None:
        t = time.monotonic()
        msg = deserialize_message(data, TYPES[topic])
        # "sha": of the content, "raw_sha": of the bytes exactly as they arrived
        received.append({"topic": topic, "sha": content_digest(msg), "raw_sha": hashlib.sha256(data).hexdigest(),
                         "stamp": stamp_of(msg), "t": t})

    subs = [node.create_subscription(cls, t, lambda data, t=t: on_message(t, data), qos_for(t), raw=True)
            for t, cls in TYPES.items()]
    print(f"listening on {len(subs)} topics", flush=True)
    deadline = time.monotonic() + args.timeout
    while len(received) < args.expect and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    with open(args.out, "w") as f:
        json.dump(received, f)
    print(f"received {len(received)}", flush=True)
    wait_for_sigint()  # stay matched so the player's last messages are acknowledged
    return 0


def main() -> int:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="mode", required=True)
    pub = sub.add_parser("publish")
    pub.add_argument("--out", required=True)
    pub.add_argument("--strings", type=int, default=20)
    pub.add_argument("--images", type=int, default=10)
    pub.add_argument("--image-every", type=int, default=2, help="one image every N ticks")
    pub.add_argument("--image-size", default="640x480")
    pub.add_argument("--period", type=float, default=0.05, help="s between ticks")
    pub.add_argument("--subscribers", type=int, default=1)
    pub.add_argument("--timeout", type=float, default=30)
    lis = sub.add_parser("listen")
    lis.add_argument("--out", required=True)
    lis.add_argument("--expect", type=int, required=True)
    lis.add_argument("--timeout", type=float, default=30)
    args = parser.parse_args()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        return publish(args) if args.mode == "publish" else listen(args)
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())

"""Self-check of the installation: two processes exchange one of our messages over DDS.

`ros2 run stud_planner selfcheck` publishes a StudLayout and starts a second process
(this module with ``--echo``) that subscribes to it and publishes it back; the check
passes when the echo arrives with the same content. It proves the venv, the ROS 2
wheels, Fast DDS on loopback and our generated interfaces work together.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time

import rclpy
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from stud_welding_msgs.msg import Stud, StudLayout

# Reliable + transient local, as /drawing/layout: the echo process may join late.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _layout() -> StudLayout:
    msg = StudLayout()
    msg.header.frame_id = "drawing"
    msg.source_file = "selfcheck"
    msg.source_units = "mm"
    msg.mark_a = Point(x=0.15)
    msg.mark_b = Point(y=0.1)
    msg.studs = [Stud(id=f"S{i:04d}", x=0.01 * i, y=0.02, diameter=0.016, layer="STUDS") for i in range(1, 4)]
    return msg


def _echo(timeout_s: float) -> int:
    node = Node("selfcheck_echo")
    pub = node.create_publisher(StudLayout, "/selfcheck/echo", LATCHED)
    got: list[StudLayout] = []
    node.create_subscription(StudLayout, "/selfcheck/layout", got.append, LATCHED)
    deadline = time.monotonic() + timeout_s
    while not got and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    if not got:
        return 1
    pub.publish(got[0])
    end = time.monotonic() + 2.0  # keep the latched echo alive until the checker has it
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    return 0


def _check(timeout_s: float) -> int:
    node = Node("selfcheck")
    sent = _layout()
    pub = node.create_publisher(StudLayout, "/selfcheck/layout", LATCHED)
    got: list[StudLayout] = []
    node.create_subscription(StudLayout, "/selfcheck/echo", got.append, LATCHED)
    pub.publish(sent)
    child = subprocess.Popen([sys.executable, "-m", "stud_planner.selfcheck", "--echo", "--timeout", str(timeout_s)])
    t0 = time.monotonic()
    try:
        while not got and time.monotonic() - t0 < timeout_s:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        child.wait(timeout=10)
    if not got:
        print(f"self-check FAILED: no echo from the second process within {timeout_s:.0f} s "
              "(is DDS blocked? ROS_AUTOMATIC_DISCOVERY_RANGE / ROS_DOMAIN_ID?)", file=sys.stderr)
        return 1
    echo = got[0]
    if [(s.id, s.x) for s in echo.studs] != [(s.id, s.x) for s in sent.studs]:
        print("self-check FAILED: the echoed StudLayout differs from the one sent", file=sys.stderr)
        return 1
    print(f"self-check passed: StudLayout with {len(echo.studs)} studs went to a second process and back "
          f"over DDS in {time.monotonic() - t0:.2f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    """`ros2 run stud_planner selfcheck`: 0 when the echo came back the same, 1 when not, 130 on Ctrl-C."""
    parser = argparse.ArgumentParser(prog="selfcheck", description=__doc__.splitlines()[0])
    parser.add_argument("--echo", action="store_true", help="be the echoing second process")
    parser.add_argument("--timeout", type=float, default=20.0, help="seconds to wait for the other process")
    args, _ros_args = parser.parse_known_args(argv if argv is not None else sys.argv[1:])
    rclpy.init()
    try:
        return _echo(args.timeout) if args.echo else _check(args.timeout)
    except KeyboardInterrupt:
        return 130
    finally:
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    sys.exit(main())

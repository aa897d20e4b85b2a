"""Second process for test_interfaces_roundtrip: echoes every message type and serves WeldJob.

For each of our message types it subscribes to /rt/<Type> and publishes what it got on
/rt/<Type>/echo. The WeldJob action server answers a goal with one feedback per target
and a result built from the goal, so the test can check all three parts of the action.
"""
import sys
import time

import rclpy
from rclpy.action import ActionServer
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from stud_welding_msgs import msg as m
from stud_welding_msgs.action import WeldJob

from stud_common import ros_io

TYPES = [m.Stud, m.StudLayout, m.Registration, m.WeldTarget, m.WeldTargetArray, m.ArmState]
QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def main() -> int:
    rclpy.init()
    node = Node("echo_all_interfaces")
    keep = []
    for t in TYPES:
        pub = node.create_publisher(t, f"/rt/{t.__name__}/echo", QOS)
        keep.append(node.create_subscription(t, f"/rt/{t.__name__}", pub.publish, QOS))

    def execute(goal_handle):
        targets = goal_handle.request.targets
        # The client's feedback subscription may match a moment after its goal request arrived.
        deadline = time.monotonic() + 5.0
        while node.count_subscribers("/rt/weld_job/_action/feedback") < 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        for i, t in enumerate(targets):
            fb = WeldJob.Feedback(stud_id=t.stud_id, phase="weld", done=i + 1, total=len(targets))
            goal_handle.publish_feedback(fb)
        goal_handle.succeed()
        return WeldJob.Result(welded=[t.stud_id for t in targets], skipped=[], failed=["none"],
                              messages=[f"{t.stud_id}: {t.pose.position.z:.4f}" for t in targets],
                              success=True, message="echo")

    ActionServer(node, WeldJob, "/rt/weld_job", execute)
    print("echo ready", flush=True)
    try:
        ros_io.spin_until_shutdown(node)
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())

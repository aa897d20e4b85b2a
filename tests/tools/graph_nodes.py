"""A small live graph for the introspection-verb tests: `python graph_nodes.py` runs node `/demo_talker`.

It has parameters (``greeting`` string, ``rate_hz`` double with a range, ``read_only_value``), publishes
``/chatter`` (std_msgs/String, 10 Hz, reliable) and a latched ``/latched`` (std_msgs/String), subscribes
``/heard`` and prints what arrives there (``heard: <data>``), serves ``/demo_talker/reset`` (std_srvs/Trigger)
and the action ``/demo_job`` (stud_welding_msgs/action/WeldJob: every target's stud id comes back welded,
with one feedback per target). Stops on SIGINT.
"""
from __future__ import annotations

import rclpy
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.action import ActionServer
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from std_srvs.srv import Trigger
from stud_welding_msgs.action import WeldJob

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Talker(Node):
    def __init__(self) -> None:
        super().__init__("demo_talker")
        self.declare_parameter("greeting", "hello", ParameterDescriptor(description="what /chatter says"))
        self.declare_parameter("rate_hz", 10.0, ParameterDescriptor(
            description="/chatter rate", floating_point_range=[FloatingPointRange(from_value=1.0, to_value=50.0)]))
        self.declare_parameter("read_only_value", 3, ParameterDescriptor(read_only=True))
        self.count = 0
        self.pub = self.create_publisher(String, "/chatter", 10)
        self.create_publisher(String, "/latched", LATCHED).publish(String(data="latched once"))
        self.create_subscription(String, "/heard", lambda m: print(f"heard: {m.data}", flush=True), 10)
        self.create_service(Trigger, "~/reset", self._reset)
        ActionServer(self, WeldJob, "/demo_job", self._execute)
        self.create_timer(0.1, self._tick)
        print("demo_talker up", flush=True)

    def _tick(self) -> None:
        self.count += 1
        self.pub.publish(String(data=f"{self.get_parameter('greeting').value} {self.count}"))

    def _reset(self, _req, resp):
        self.count = 0
        resp.success, resp.message = True, "counter reset"
        return resp

    def _execute(self, goal_handle):
        ids = [t.stud_id for t in goal_handle.request.targets]
        for i, sid in enumerate(ids):
            goal_handle.publish_feedback(WeldJob.Feedback(stud_id=sid, phase="weld", done=i + 1, total=len(ids)))
        goal_handle.succeed()
        return WeldJob.Result(welded=ids, success=True, message=f"{len(ids)} welded")


def main() -> None:
    rclpy.init()
    node = Talker()
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()

"""Every message type of stud_welding_msgs, and the WeldJob action, survives DDS between two processes."""
from __future__ import annotations

import math

import pytest
import rclpy
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from stud_welding_msgs import msg as m
from stud_welding_msgs.action import WeldJob

from rosproc import REPO, python_proc, wait_for

QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _target(i: int) -> m.WeldTarget:
    return m.WeldTarget(
        stud_id=f"S{i:04d}", drawing_x=0.1 * i, drawing_y=-0.05,
        pose=Pose(position=Point(x=0.3, y=0.02 * i, z=0.041), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
        normal=Vector3(x=0.01, y=-0.02, z=0.9997), pixel_u=640.25, pixel_v=480.5, view_index=3, iterations=7,
        xy_error=0.0003, inclination=4.1, normal_rms=0.0002, status=m.WeldTarget.STATUS_NORMAL_UNCERTAIN,
        status_text="normal_uncertain", normal_sigma=1.9, lean_bound=6.2, fill_ratio=0.4, gun_clearance=0.012)


def _samples() -> list:
    stud = m.Stud(id="S0001", x=0.125, y=-0.25, diameter=0.016, layer="STUDS")
    layout = m.StudLayout(source_file="/tmp/dome.dxf", source_units="mm", mark_a=Point(x=0.15),
                          mark_b=Point(y=0.1), mark_diameter=0.02, studs=[stud, stud], warnings=["w1"])
    layout.header.frame_id = "drawing"
    layout.header.stamp.sec = 42
    reg = m.Registration(m_local2world=[0.0, -1.0, 0.3, 1.0, 0.0, -0.1, 0.0, 0.0, 1.0], mark_o=Point(x=0.3, y=-0.1),
                         residual=0.0004, angle_aob=math.pi / 2, valid=True, message="ok")
    arr = m.WeldTargetArray(targets=[_target(1), _target(2)], algorithm="batch", match_time=0.012,
                            total_iterations=14, view_index=3)
    arm = m.ArmState(mode=m.ArmState.MODE_WELDING, joints=[0.1, -0.2, 0.3, -0.4, 0.5, -0.6], current_stud="S0002",
                     done=1, total=2, error_codes=[0x1001], errors=["joint 1 overcurrent"], connected=True, message="m")
    return [stud, layout, reg, _target(5), arr, arm]


@pytest.fixture()
def echo_process(tmp_path):
    proc = python_proc(str(REPO / "tests" / "ros" / "echo_all_interfaces.py"), [], tmp_path / "echo.log")
    wait_for(lambda: "echo ready" in proc.output() or proc.popen.poll() is not None, 30, what="echo process")
    assert proc.popen.poll() is None, proc.output()
    yield proc
    proc.stop()


def test_every_message_type_round_trips_between_processes(echo_process):
    rclpy.init()
    try:
        node = Node("roundtrip_test")
        received: dict[str, object] = {}
        for sample in _samples():
            name = type(sample).__name__
            pub = node.create_publisher(type(sample), f"/rt/{name}", QOS)
            node.create_subscription(type(sample), f"/rt/{name}/echo",
                                     lambda msg, name=name: received.setdefault(name, msg), QOS)
            pub.publish(sample)
        wait_for(lambda: len(received) == 6, 30, spin=lambda: rclpy.spin_once(node, timeout_sec=0.05),
                 what=f"echoes (got {sorted(received)})\n{echo_process.output()}")
        for sample in _samples():
            assert received[type(sample).__name__] == sample, type(sample).__name__
        # spot-check a few values by hand too: equality of generated classes is what we rely on above
        assert received["WeldTargetArray"].targets[1].pose.position.y == pytest.approx(0.04)
        assert received["ArmState"].errors == ["joint 1 overcurrent"]
        assert list(received["Registration"].m_local2world)[2] == pytest.approx(0.3)
    finally:
        rclpy.shutdown()


def test_weld_job_action_goal_feedback_and_result_round_trip(echo_process):
    rclpy.init()
    try:
        node = Node("action_test")
        client = ActionClient(node, WeldJob, "/rt/weld_job")
        spin = lambda: rclpy.spin_once(node, timeout_sec=0.05)  # noqa: E731
        wait_for(lambda: client.server_is_ready(), 30, spin=spin, what="WeldJob server")
        # A warm-up goal: "server ready" means its services are matched, not yet the feedback topic.
        warm = client.send_goal_async(WeldJob.Goal(targets=[_target(9)]))
        wait_for(warm.done, 30, spin=spin, what="warm-up goal")
        warm_result = warm.result().get_result_async()
        wait_for(warm_result.done, 30, spin=spin, what="warm-up result")
        feedback: list[WeldJob.Feedback] = []
        goal = WeldJob.Goal(targets=[_target(1), _target(2), _target(3)], resume=True)
        future = client.send_goal_async(goal, feedback_callback=lambda fb: feedback.append(fb.feedback))
        wait_for(future.done, 30, spin=spin, what="goal acceptance")
        handle = future.result()
        assert handle.accepted
        # All feedback first: rclpy's client drops a goal's feedback callback once its result is in,
        # and the result may overtake the last feedback messages on another DDS topic.
        wait_for(lambda: len(feedback) == 3, 30, spin=spin, what=f"feedback (got {feedback})")
        result_future = handle.get_result_async()
        wait_for(result_future.done, 30, spin=spin, what="result")
        result = result_future.result().result
        assert result.welded == ["S0001", "S0002", "S0003"]
        assert result.messages[0] == "S0001: 0.0410"  # the goal's nested pose reached the server
        assert result.success and result.failed == ["none"]
        assert [(f.stud_id, f.done, f.total) for f in feedback] == [("S0001", 1, 3), ("S0002", 2, 3), ("S0003", 3, 3)]
    finally:
        rclpy.shutdown()

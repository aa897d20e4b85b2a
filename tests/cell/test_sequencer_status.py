"""What the cell sequencer's /cell/status says for the HMI's plan, over DDS: where the camera was
moved (the station's footprint on the registered plane) and why each unreachable stud is."""
from __future__ import annotations

import time

import pytest
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from stud_welding_msgs.msg import ArmState, CellStatus, Registration
from stud_welding_msgs.srv import MoveTo

from sequencer_harness import sequencer_beside
from stud_cell import job as cell_job
from stud_common import names, ros_io

PLANE_Z = 0.05  # the registered marks' height: the part lies on a table 50 mm above the arm's base


class FakeArm(Node):
    """/arm/move_to (always arrives) and /arm/state after it; a /cell/status listener."""

    def __init__(self) -> None:
        super().__init__("fake_arm")
        group = ReentrantCallbackGroup()
        self.moves: list[MoveTo.Request] = []
        self.create_service(MoveTo, names.ARM_MOVE_TO, self._on_move, callback_group=group)
        self.pub = self.create_publisher(ArmState, names.ARM_STATE, ros_io.RESULT_QOS)
        self.pub_reg = self.create_publisher(Registration, names.REGISTRATION_RESULT, ros_io.LATCHED_QOS)
        self.statuses: list[CellStatus] = []
        self.create_subscription(CellStatus, names.CELL_STATUS, self.statuses.append, ros_io.LATCHED_QOS,
                                 callback_group=group)
        self.create_timer(0.05, self._publish, callback_group=group)

    def _on_move(self, req, resp):
        self.moves.append(req)
        resp.success, resp.message = True, "arrived"
        return resp

    def _publish(self) -> None:
        msg = ArmState(mode=ArmState.MODE_IDLE, connected=True)
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub.publish(msg)


@pytest.fixture()
def cell():
    with sequencer_beside(FakeArm) as nodes:
        yield nodes


def wait(predicate, what: str, timeout_s: float = 10.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def test_the_status_carries_the_camera_footprint_and_the_reasons_of_unreachable_studs(cell):
    sequencer, arm = cell
    reg = Registration(valid=True, message="test")
    reg.mark_o.z = PLANE_Z
    arm.pub_reg.publish(reg)
    wait(lambda: sequencer.registration is not None and sequencer.arm_state is not None, "registration and arm state")
    assert list(sequencer.cell_status.camera_xyz_m) == []  # not known before the first move

    sequencer.move_camera((0.3, -0.1, PLANE_Z + 0.40), 0.5)
    p = sequencer.p
    width = p["fov_width_m"] * (0.40 - p["part_height_m"]) / p["fov_distance_m"]  # on the part's top
    st = sequencer.cell_status
    assert list(st.camera_xyz_m) == pytest.approx([0.3, -0.1, PLANE_Z + 0.40]) and st.camera_yaw_rad == 0.5
    assert list(st.camera_footprint_m) == pytest.approx([width, width * p["image_aspect"]])
    sequencer.move_camera((0.3, -0.1, PLANE_Z + 0.1), 0.0)  # below the part's top: no footprint to draw
    assert list(sequencer.cell_status.camera_footprint_m) == []

    # the studs named unreachable carry their QA rows' reasons, one per id
    sequencer.job = cell_job.CellJob(sequencer, cell_job.JobConfig())
    sequencer.job.qa = {"S1": {"reasons": ["unreachable: no camera station the arm reaches covers it"]},
                        "S2": {"reasons": []}}
    sequencer.status(cell_job.REGISTERING, "registered", unreachable=["S1", "S2"], stations_total=3)
    got = wait(lambda: next((s for s in reversed(arm.statuses) if list(s.unreachable) == ["S1", "S2"]), None),
               "/cell/status with the unreachable studs")
    assert list(got.unreachable_reasons) == ["unreachable: no camera station the arm reaches covers it", "unreachable"]
    assert list(got.camera_xyz_m) == pytest.approx([0.3, -0.1, PLANE_Z + 0.1])
    assert (got.state, got.state_text) == (CellStatus.STATE_REGISTERING, "registering")  # the job's CellState, sent
    # a job that names its reasons itself is taken at its word
    sequencer.status(cell_job.REGISTERING, "registered", unreachable=["S2"], unreachable_reasons=["its own"])
    assert list(sequencer.cell_status.unreachable_reasons) == ["its own"]

"""The cell sequencer's rail ports over DDS (CellPorts.move_rail, rail_position_m): the carriage moved
through /arm/rail_move, its arrival confirmed by /arm/state at the new position before the job goes on
(the camera is posed from /arm/state); a refused move is MoveRefused (the job loses that carriage
position), an e-stop or a running weld job stops the job."""
from __future__ import annotations

import pytest
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from stud_welding_msgs.msg import ArmState
from stud_welding_msgs.srv import RailMove

from sequencer_harness import sequencer_beside
from stud_cell.job import JobAborted, MoveRefused
from stud_common import names, ros_io


class FakeRailArm(Node):
    """/arm/rail_move that takes the carriage there (or refuses with ``refusal``) and /arm/state showing it,
    the carriage reported moving for a few states after each move."""

    def __init__(self) -> None:
        super().__init__("fake_rail_arm")
        group = ReentrantCallbackGroup()
        self.carriage, self.moving_states, self.refusal = 0.25, 0, ""
        self.requests: list[RailMove.Request] = []
        self.create_service(RailMove, names.ARM_RAIL_MOVE, self._on_rail_move, callback_group=group)
        self.pub = self.create_publisher(ArmState, names.ARM_STATE, ros_io.RESULT_QOS)
        self.create_timer(0.05, self._publish, callback_group=group)

    def _on_rail_move(self, req, resp):
        self.requests.append(req)
        if self.refusal:
            resp.success, resp.message, resp.position_m = False, self.refusal, self.carriage
            return resp
        self.carriage, self.moving_states = req.position_m, 3
        resp.success, resp.message, resp.position_m = True, f"carriage at {req.position_m:.4f} m", self.carriage
        return resp

    def _publish(self) -> None:
        msg = ArmState(mode=ArmState.MODE_IDLE, connected=True, rail_position_m=self.carriage,
                       rail_moving=self.moving_states > 0)
        self.moving_states = max(0, self.moving_states - 1)
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub.publish(msg)


@pytest.fixture()
def cell():
    with sequencer_beside(FakeRailArm) as nodes:
        yield nodes


def test_the_carriage_moves_through_rail_move_and_the_job_waits_for_the_state_showing_it_there(cell):
    sequencer, arm = cell
    assert sequencer.rail_position_m() == pytest.approx(0.25)
    assert sequencer.move_rail(1.5) == pytest.approx(1.5)
    assert arm.requests[-1].position_m == 1.5 and arm.requests[-1].speed_pct == 0   # the driver's rail_speed_pct
    st = sequencer.arm_state
    assert st is not None and st.rail_position_m == pytest.approx(1.5) and not st.rail_moving
    assert sequencer.rail_position_m() == pytest.approx(1.5)


@pytest.mark.parametrize("refusal, error", [
    ("rail position 7.000 m outside the travel 0 .. 6 m", MoveRefused),
    ("e-stop engaged", JobAborted),
    ("a weld job is running: the carriage moves only between jobs", JobAborted),
])
def test_a_refused_carriage_move_says_why_and_only_an_e_stop_or_a_weld_job_stops_the_job(cell, refusal, error):
    sequencer, arm = cell
    arm.refusal = refusal
    with pytest.raises(JobAborted) as info:
        sequencer.move_rail(7.0)
    assert type(info.value) is error and refusal in str(info.value) and "7.0000 m" in str(info.value)

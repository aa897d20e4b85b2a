"""The cell sequencer's weld step against an arm driver whose /arm/state stream stalls, over DDS.

A driver process starved of CPU (a loaded cell PC) goes silent for longer than ``driver_lost_s`` and
comes back before it has started the job's studs: to the sequencer that looks like a restarted
driver. It sends the station again; the driver, still on the first job, rejects that. The job
must then wait for the first job's result, not abort while the arm goes on welding studs that the
report would then say are not welded."""
from __future__ import annotations

import time

import pytest
from rclpy.action import ActionServer, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from stud_welding_msgs.action import WeldJob
from stud_welding_msgs.msg import ArmState, WeldTarget

from sequencer_harness import sequencer_beside
from stud_cell import job as cell_job
from stud_common import names, ros_io

IDS = ["S0001", "S0002", "S0003"]
SILENT_S, NOT_STARTED_S, WELDING_S = 2.0, 2.5, 1.5  # the driver's stall, then its slow job start


class StallingDriver(Node):
    """/arm/weld_job and /arm/state as the driver serves them, with a stall at the job's start:
    no state for SILENT_S, then NOT_STARTED_S of states showing no job running, then the job."""

    def __init__(self) -> None:
        super().__init__("stalling_driver")
        group = ReentrantCallbackGroup()
        self.pub = self.create_publisher(ArmState, names.ARM_STATE, ros_io.RESULT_QOS)
        self.running = False
        self.silent = False
        self.total = 0
        self.goals = {"accepted": 0, "rejected": 0}
        self.server = ActionServer(self, WeldJob, names.ARM_WELD_JOB, execute_callback=self._execute,
                                   goal_callback=self._on_goal, callback_group=group)
        self.create_timer(0.1, self._publish, callback_group=group)

    def _publish(self) -> None:
        if self.silent:
            return
        msg = ArmState(mode=ArmState.MODE_MOVING if self.total else ArmState.MODE_IDLE, connected=True,
                       total=self.total)
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub.publish(msg)

    def _on_goal(self, _goal) -> GoalResponse:
        if self.running:  # as the real driver: one job at a time
            self.goals["rejected"] += 1
            return GoalResponse.REJECT
        self.running = True
        self.goals["accepted"] += 1
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle) -> WeldJob.Result:
        ids = [t.stud_id for t in goal_handle.request.targets]
        self.silent = True
        time.sleep(SILENT_S)
        self.silent = False
        time.sleep(NOT_STARTED_S)
        self.total = len(ids)
        time.sleep(WELDING_S)
        self.total, self.running = 0, False
        goal_handle.succeed()
        return WeldJob.Result(welded=ids, success=True, message=f"done: {len(ids)} welded")


@pytest.fixture()
def cell():
    with sequencer_beside(StallingDriver, threads=6) as nodes:
        yield nodes


def test_a_resend_rejected_by_a_driver_still_on_the_job_waits_for_that_jobs_result(cell):
    sequencer, driver = cell
    deadline = time.monotonic() + 10.0
    while sequencer.arm_state is None and time.monotonic() < deadline:  # discovery
        time.sleep(0.05)
    assert sequencer.arm_state is not None, "no /arm/state reached the sequencer"
    job = cell_job.CellJob(sequencer, cell_job.JobConfig())
    for sid in IDS:
        job.stud_report[sid] = {"stud_id": sid, "status": "ok", "welded": False}
    targets = [cell_job.Target(stud_id=sid, ok=True, status_text="ok", lean_bound_deg=1.0, entry={},
                               payload=WeldTarget(stud_id=sid)) for sid in IDS]
    welded = job._weld(targets)  # the job's own resend loop (weld_resends), as a station runs it
    assert welded == set(IDS), (welded, driver.goals)
    assert all(job.stud_report[sid]["welded"] for sid in IDS)
    # it did believe the driver lost and sent the station again, which the busy driver rejected
    assert driver.goals == {"accepted": 1, "rejected": 1}, driver.goals

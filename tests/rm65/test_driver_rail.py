"""The driver on a rail, as a real process over DDS against the simulator's expansion joint (real TCP).

The carriage moves on /arm/rail_move (and /arm/move_to with move_rail), shows in /arm/state and as the
prismatic rail_joint in /joint_states; weld targets arrive in world and are welded at the right place
in the arm's base frame; a rail move is refused during a weld job; a stop stops the carriage.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("stud_welding_msgs.srv", reason="workspace not built/sourced (source ros2_ws/setup.bash)")

from rclpy.action import ActionClient  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from stud_welding_msgs.action import WeldJob  # noqa: E402
from stud_welding_msgs.msg import ArmState, WeldRecord  # noqa: E402
from stud_welding_msgs.srv import MoveTo, RailMove  # noqa: E402

from rm65_driver.kinematics.rm65 import RM65Kinematics, matrix_to_quat_xyzw  # noqa: E402
from rm65_driver.rail.axis import RailAxis  # noqa: E402
from rm65_driver.weld.weld_job import StudTarget  # noqa: E402
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator  # noqa: E402
from rm65_testing import FAST, HOME_DEG, dome_targets, welds_per_stud  # noqa: E402
from stud_common.frames import world_T_base  # noqa: E402
from test_driver_node import RELIABLE_10, NodeProc, call, spin_until, weld_target_msg  # noqa: E402

MOUNT = [0.05, -0.02, 0.10]  # the arm's base on the carriage
RAIL = dict(rail_length_m=6.0, rail_mount_xyz_m=MOUNT, rail_speed_pct=40, state_rate_hz=20.0,
            # the workspace box is in world, the rail's frame: it spans the rail
            workspace_min_m=[-0.7, -0.7, -0.02], workspace_max_m=[6.7, 0.7, 1.2])


@pytest.fixture
def probe():
    rclpy.init()
    node = Node("rm65_rail_test_probe")
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


@pytest.fixture
def rail_sim():
    config = SimulatorConfig(time_scale=FAST, initial_joints_deg=HOME_DEG, rail_axis=RailAxis(6.0),
                             rail_mount_xyz_m=MOUNT)
    s = ArmSimulator(port=0, config=config).start()
    yield s
    s.stop()


def in_world(targets, carriage_m):
    """Targets laid out in the arm's base frame, as the cell sends them: in world, the carriage at ``carriage_m``."""
    W = world_T_base(carriage_m, MOUNT)
    return [StudTarget(t.stud_id, W[:3, :3] @ t.position + W[:3, 3], W[:3, :3] @ t.normal) for t in targets]


def test_rail_move_joint_states_and_a_weld_job_in_world_at_one_metre(rail_sim, probe, tmp_path):
    proc = NodeProc(rail_sim.port, tmp_path, pulse_s=0.01, dwell_s=0.01, standoff_m=0.04, joint_speed_pct=50,
                    linear_speed_pct=20, **RAIL)
    try:
        states, joints, welds = [], [], []
        probe.create_subscription(ArmState, "/arm/state", states.append, RELIABLE_10)
        probe.create_subscription(JointState, "/joint_states", joints.append, RELIABLE_10)
        probe.create_subscription(WeldRecord, "/arm/welds", welds.append, RELIABLE_10)
        spin_until(probe, lambda: states and states[-1].connected and joints, 30, "/arm/state", proc)
        assert list(joints[-1].name) == [f"joint{i}" for i in range(1, 7)] + ["rail_joint"]
        assert joints[-1].position[6] == 0.0 and states[-1].rail_position_m == 0.0

        rail_move = probe.create_client(RailMove, "/arm/rail_move")
        r = call(probe, rail_move, RailMove.Request(position_m=1.0), proc)
        assert r.success and r.position_m == pytest.approx(1.0), r.message
        assert rail_sim.rail.position_m == pytest.approx(1.0)
        assert rail_sim.commands_named("expand_set_pos")[-1].msg == {"command": "expand_set_pos", "pos": 1_000_000,
                                                                     "speed": 40}
        spin_until(probe, lambda: joints[-1].position[6] == pytest.approx(1.0) and
                   states[-1].rail_position_m == pytest.approx(1.0) and not states[-1].rail_moving, 10,
                   "the carriage at 1 m in /joint_states and /arm/state", proc)
        # the tool in world: the base's FK moved by the carriage and the mount
        T = RM65Kinematics().fk(rail_sim.joints)
        p = states[-1].tool_pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], (T @ [0, 0, 0.15, 1])[:3] + [1.0 + MOUNT[0], MOUNT[1], MOUNT[2]],
                                   atol=1e-5)

        for bad, why in ((6.5, "outside the travel 0..6 m"), (-0.1, "outside the travel")):
            r = call(probe, rail_move, RailMove.Request(position_m=bad), proc)
            assert not r.success and why in r.message and r.position_m == pytest.approx(1.0)

        base_targets = dome_targets(rings=((0.0, 1), (0.05, 5)))  # reachable from the base, as in the other tests
        targets = in_world(base_targets, 1.0)
        assert all(t.position[0] > 1.2 for t in targets)  # far outside the arm's reach from the rail's zero
        action = ActionClient(probe, WeldJob, "/arm/weld_job")
        spin_until(probe, lambda: action.server_is_ready(), 20, "action server", proc)
        feedback = []
        fut = action.send_goal_async(WeldJob.Goal(targets=[weld_target_msg(t) for t in targets]),
                                     feedback_callback=lambda f: feedback.append(f.feedback))
        spin_until(probe, fut.done, 20, "goal acceptance", proc)
        handle = fut.result()
        # a rail move during the job is refused (the job is paused, so it surely still runs)
        spin_until(probe, lambda: feedback, 30, "the job's first feedback", proc)
        assert call(probe, probe.create_client(Trigger, "/arm/pause"), Trigger.Request(), proc).success
        r = call(probe, rail_move, RailMove.Request(position_m=2.0), proc)
        assert not r.success and "weld job is running" in r.message
        assert call(probe, probe.create_client(Trigger, "/arm/resume"), Trigger.Request(), proc).success
        rfut = handle.get_result_async()
        spin_until(probe, rfut.done, 60, "job result", proc)
        res = rfut.result().result
        assert res.success and list(res.welded) == [t.stud_id for t in targets], res.message
        # welded once each, at the base-frame positions the world targets are at from a carriage at 1 m
        counts = welds_per_stud(rail_sim, base_targets, tol_m=1e-4)
        assert all(c == 1 for c in counts.values()), counts
        assert rail_sim.rail.position_m == pytest.approx(1.0)
        P_world = np.array([t.position for t in targets])
        for e in rail_sim.rising_edges(1):  # the truth (no rail error here): on a world target
            assert np.min(np.linalg.norm(P_world - e.true_world_position, axis=1)) < 1e-4
        # the journal's weld points and /arm/welds are in world
        started = [json.loads(x) for x in (tmp_path / "journal.jsonl").read_text().splitlines()]
        started = {r["stud"]: r for r in started if r["event"] == "started"}
        for t in targets:
            np.testing.assert_allclose(started[t.stud_id]["position"], t.position, atol=1e-9)
            assert started[t.stud_id]["rail_position_m"] == pytest.approx(1.0)  # the carriage of the weld
        spin_until(probe, lambda: len(welds) == len(targets), 10, "/arm/welds", proc)
        for w in welds:
            t = next(x for x in targets if x.stud_id == w.stud_id)
            assert w.rail_position_m == pytest.approx(1.0)
            pw = w.tool_pose.position
            assert np.linalg.norm([pw.x - t.position[0], pw.y - t.position[1], pw.z - t.position[2]]) < 2e-4
        assert not any(c.name == "expand_set_pos" and c.t > rail_sim.commands_named("movej")[0].t
                       and c.t < rail_sim.rising_edges(1)[-1].t for c in rail_sim.commands)
    finally:
        code = proc.stop()
    assert code == 0, proc.log_path.read_text()[-3000:]


def test_move_to_with_the_carriage_and_a_stop_that_stops_the_rail(rail_sim, probe, tmp_path):
    from stud_perception.camera_model import nadir_rotation

    proc = NodeProc(rail_sim.port, tmp_path, hand_eye_xyz_m=[0.05, 0.0, -0.10], **RAIL)
    try:
        move = probe.create_client(MoveTo, "/arm/move_to")
        req = MoveTo.Request(frame=MoveTo.Request.FRAME_TOOL, move_rail=True, rail_position_m=2.5)
        goal = np.array([2.5 + MOUNT[0] + 0.30, MOUNT[1] + 0.05, MOUNT[2] + 0.20])
        req.pose.position.x, req.pose.position.y, req.pose.position.z = goal
        x, y, z, w = matrix_to_quat_xyzw(nadir_rotation(0.0))
        req.pose.orientation.x, req.pose.orientation.y, req.pose.orientation.z, req.pose.orientation.w = x, y, z, w
        r = call(probe, move, req, proc)
        assert r.success, r.message
        assert rail_sim.rail.position_m == pytest.approx(2.5)
        tool = np.eye(4)
        tool[2, 3] = 0.15
        np.testing.assert_allclose((world_T_base(2.5, MOUNT) @ RM65Kinematics().fk(rail_sim.joints) @ tool)[:3, 3],
                                   goal, atol=1e-4)
        # the carriage moved first, the arm after it arrived
        rail_t = rail_sim.rail.arrivals[-1][0]
        assert all(c.t > rail_t for c in rail_sim.commands_named("movej"))
        # a pose the arm cannot reach from where the carriage would be: nothing moves
        n_cmds = len(rail_sim.commands_named("expand_set_pos"))
        req.rail_position_m = 0.0
        r = call(probe, move, req, proc)
        assert not r.success and "with the carriage at 0.000 m" in r.message
        assert len(rail_sim.commands_named("expand_set_pos")) == n_cmds

        # a slow rail move, stopped by /arm/stop: the carriage halts, the move reports the stop
        rail_move = probe.create_client(RailMove, "/arm/rail_move")
        spin_until(probe, rail_move.service_is_ready, 20, "/arm/rail_move", proc)
        fut = rail_move.call_async(RailMove.Request(position_m=5.5, speed_pct=5))
        spin_until(probe, lambda: rail_sim.rail.position_m > 2.6, 20, "the carriage under way", proc)
        assert call(probe, probe.create_client(Trigger, "/arm/stop"), Trigger.Request(), proc).success
        spin_until(probe, fut.done, 20, "the rail move's reply", proc)
        assert not fut.result().success and "stop" in fut.result().message
        assert not rail_sim.rail.moving and 2.6 < rail_sim.rail.position_m < 5.5
        assert rail_sim.rail.arrivals[-1][1] is False
        assert rail_sim.commands_named("expand_set_speed")[-1].msg["speed"] == 0
    finally:
        code = proc.stop()
    assert code == 0, proc.log_path.read_text()[-3000:]


@pytest.mark.parametrize("params, expected", [
    (["rail_length_m:=100.0", "rail_pos_unit_m:=1e-08"], "bad parameter rail of 100.0 m at 1e-08 m per count needs "
                                                         "10000000000 counts: beyond the wire's int32 pos"),
    (["rail_length_m:=-1.0"], "bad parameter rail_length_m=-1.0: expected a number in [0.0, 100.0]"),
    (["rail_length_m:=3.0", "rail_mount_xyz_m:=[0.0,0.1]"], "rail_mount_xyz_m needs 3 numbers, got [0.0, 0.1]"),
])
def test_a_bad_rail_ends_the_driver_with_one_line_and_exit_code_2(tmp_path, params, expected):
    import os
    import subprocess
    import sys
    from pathlib import Path

    src = Path(__file__).resolve().parents[2] / "src"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(src / "rm65_driver"), str(src / "stud_perception"),
                                                       os.environ.get("PYTHONPATH", "")]))
    args = [a for p in [f"journal_file:={tmp_path / 'j.jsonl'}", *params] for a in ("-p", p)]
    done = subprocess.run([sys.executable, "-m", "rm65_driver.driver.driver_node", "--ros-args", *args], env=env,
                          capture_output=True, text=True, timeout=60)
    lines = [x for x in (done.stdout + done.stderr).splitlines() if x.strip()]
    assert done.returncode == 2 and len(lines) == 1 and "[FATAL]" in lines[0], lines
    assert expected in lines[0], lines[0]

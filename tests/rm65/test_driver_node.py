"""The driver node as a real process over DDS, against the simulator in this test process.

Needs the built workspace (``source ros2_ws/setup.bash``); skipped otherwise. The node runs
from the source tree (PYTHONPATH) so a change is tested without a rebuild.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("stud_welding_msgs.msg", reason="workspace not built/sourced (source ros2_ws/setup.bash)")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from stud_welding_msgs.action import WeldJob  # noqa: E402
from stud_welding_msgs.msg import ArmState, WeldTarget  # noqa: E402
from stud_welding_msgs.srv import ResolveStud  # noqa: E402

from rm65_driver.kinematics.rm65 import RM65Kinematics, matrix_to_quat_xyzw, quat_xyzw_to_matrix, tool_pose_facing  # noqa: E402
from rm65_testing import dome_targets, welds_per_stud  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
RELIABLE_10 = 10


class NodeProc:
    def __init__(self, port: int, tmp_path: Path, **params):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src" / "rm65_driver"), str(REPO / "src" / "stud_perception"),
                                             env.get("PYTHONPATH", "")])
        args = ["--ros-args", "-p", f"tcp_port:={port}", "-p", f"journal_file:={tmp_path / 'journal.jsonl'}"]
        for k, v in params.items():
            args += ["-p", f"{k}:={json.dumps(v) if not isinstance(v, bool) else str(v).lower()}"]
        self.log = open(tmp_path / "driver.log", "w")
        self.popen = subprocess.Popen([sys.executable, "-u", "-m", "rm65_driver.driver.driver_node", *args], env=env,
                                      stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        self.log_path = tmp_path / "driver.log"

    def output(self) -> str:
        self.log.flush()
        return self.log_path.read_text(errors="replace")[-3000:]

    def stop(self) -> int:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait()
        self.log.close()
        return self.popen.returncode


@pytest.fixture
def probe():
    rclpy.init()
    node = Node("rm65_test_probe")
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def spin_until(node, cond, timeout, what, proc=None):
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}\n{proc.output() if proc else ''}")
        rclpy.spin_once(node, timeout_sec=0.02)


def call(node, client, request, proc, timeout=20):
    spin_until(node, client.service_is_ready, timeout, f"service {client.srv_name}", proc)
    fut = client.call_async(request)
    spin_until(node, fut.done, timeout, f"reply of {client.srv_name}", proc)
    return fut.result()


def weld_target_msg(t, status=WeldTarget.STATUS_OK) -> WeldTarget:
    m = WeldTarget()
    m.stud_id = t.stud_id
    m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in t.position)
    T = tool_pose_facing(t.position, -t.normal)  # z axis along the outward normal
    x, y, z, w = matrix_to_quat_xyzw(T[:3, :3])
    m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = x, y, z, w
    m.normal.x, m.normal.y, m.normal.z = (float(v) for v in t.normal)
    m.status = status
    m.status_text = "ok" if status == WeldTarget.STATUS_OK else "no_depth"
    return m


def test_driver_node_runs_a_weld_job_and_publishes_state(sim, probe, tmp_path):
    proc = NodeProc(sim.port, tmp_path, pulse_s=0.01, dwell_s=0.01, standoff_m=0.04, state_rate_hz=20.0,
                    publish_camera_pose=True, hand_eye_xyz_m=[0.05, 0.0, 0.0], hand_eye_rpy_deg=[0.0, 0.0, 90.0],
                    joint_speed_pct=50, linear_speed_pct=20)
    try:
        states, joints, cams = [], [], []
        probe.create_subscription(ArmState, "/arm/state", states.append, RELIABLE_10)
        probe.create_subscription(JointState, "/joint_states", joints.append, RELIABLE_10)
        probe.create_subscription(PoseStamped, "/camera/pose", cams.append, RELIABLE_10)
        spin_until(probe, lambda: states and states[-1].connected and joints and cams, 30, "/arm/state", proc)
        st = states[-1]
        assert st.mode == ArmState.MODE_IDLE and st.header.frame_id == "world"
        np.testing.assert_allclose(st.joints, sim.joints, atol=1e-5)
        assert list(joints[-1].name) == [f"joint{i}" for i in range(1, 7)]
        tool = np.eye(4)
        tool[2, 3] = 0.15
        T_tool = RM65Kinematics().fk(sim.joints) @ tool
        p = st.tool_pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], T_tool[:3, 3], atol=1e-5)
        c = cams[-1].pose
        R_cam = quat_xyzw_to_matrix([c.orientation.x, c.orientation.y, c.orientation.z, c.orientation.w])
        np.testing.assert_allclose([c.position.x, c.position.y, c.position.z], T_tool[:3, 3] + 0.05 * T_tool[:3, 0],
                                   atol=1e-5)
        np.testing.assert_allclose(R_cam[:, 0], T_tool[:3, 1], atol=1e-6)  # yaw 90 deg about the tool z

        targets = dome_targets(rings=((0.0, 1), (0.05, 5)))
        tilted = type(targets[0])("TILT", [0.30, 0.09, 0.0], [np.sin(np.radians(65)), 0, np.cos(np.radians(65))])
        goal = WeldJob.Goal(targets=[weld_target_msg(t) for t in targets[:3]]
                            + [weld_target_msg(targets[3], WeldTarget.STATUS_NO_DEPTH), weld_target_msg(tilted)]
                            + [weld_target_msg(t) for t in targets[4:]], resume=True)
        action = ActionClient(probe, WeldJob, "/arm/weld_job")
        spin_until(probe, lambda: action.server_is_ready(), 20, "action server", proc)
        feedback = []
        fut = action.send_goal_async(goal, feedback_callback=lambda f: feedback.append(f.feedback))
        spin_until(probe, fut.done, 20, "goal acceptance", proc)
        handle = fut.result()
        assert handle.accepted
        welded = [t.stud_id for t in targets if t.stud_id != targets[3].stud_id]
        # The last feedback before the result: rclpy drops a goal's feedback once its result is in.
        spin_until(probe, lambda: any(f.stud_id == welded[-1] and f.phase == "retract" for f in feedback), 60,
                   "feedback of the last stud", proc)
        rfut = handle.get_result_async()
        spin_until(probe, rfut.done, 60, "job result", proc)
        res = rfut.result().result
        assert res.success, res.message
        assert list(res.welded) == welded
        assert list(res.skipped) == [targets[3].stud_id, "TILT"]
        assert "no_depth" in res.messages[0] and "tilt 65.0 deg from vertical" in res.messages[1]
        assert [f.phase for f in feedback if f.stud_id == "S0000"] == ["approach", "descend", "weld", "dwell",
                                                                          "retract"]
        assert feedback[-1].total == 7
        counts = welds_per_stud(sim, targets)
        assert counts[targets[3].stud_id] == 0 and all(counts[s] == 1 for s in welded)
        lines = (tmp_path / "journal.jsonl").read_text().splitlines()
        assert sum(json.loads(x)["event"] == "welded" for x in lines) == 5
    finally:
        assert proc.stop() == 0, proc.output()


@pytest.mark.parametrize("signs, expect", [([0, 0, 0, 0, 0, 0], -1), ([0, 0, 1, 0, 1, 0], 1)],
                         ids=["nearest", "preferred branch"])
def test_move_to_takes_the_preferred_branch(sim, probe, tmp_path, signs, expect):
    """/arm/move_to over DDS to a camera pose over the marking board that the arm reaches with
    J3, J5 of either sign: from the test's home pose (J3, J5 negative) the nearest stays negative;
    with preferred_joint_signs asking for positive the controller is sent the positive one."""
    from stud_welding_msgs.srv import MoveTo

    from stud_perception.camera_model import nadir_rotation

    proc = NodeProc(sim.port, tmp_path, preferred_joint_signs=signs, hand_eye_xyz_m=[0.05, 0.0, -0.10])
    try:
        move = probe.create_client(MoveTo, "/arm/move_to")
        req = MoveTo.Request(frame=MoveTo.Request.FRAME_CAMERA)
        req.pose.position.x, req.pose.position.y, req.pose.position.z = 0.225, -0.29, 0.285
        x, y, z, w = matrix_to_quat_xyzw(nadir_rotation(0.0))
        req.pose.orientation.x, req.pose.orientation.y, req.pose.orientation.z, req.pose.orientation.w = x, y, z, w
        r = call(probe, move, req, proc)
        assert r.success, r.message + proc.output()
        q = sim.joints
        assert np.sign(q[2]) == expect and np.sign(q[4]) == expect, np.degrees(q)
    finally:
        code = proc.stop()
    assert code == 0, proc.log_path.read_text()[-3000:]


def test_estop_stop_latency_and_resolve_over_ros(sim, probe, tmp_path):
    (tmp_path / "journal.jsonl").write_text(json.dumps({"t": "x", "event": "started", "stud": "U1"}) + "\n")
    sim.time_scale = 1.0  # real-time motion: the job is mid-move when we stop it
    proc = NodeProc(sim.port, tmp_path, pulse_s=0.01, dwell_s=0.01, joint_speed_pct=5, state_rate_hz=20.0)
    try:
        states = []
        probe.create_subscription(ArmState, "/arm/state", states.append, RELIABLE_10)
        spin_until(probe, lambda: states and states[-1].connected, 30, "/arm/state", proc)
        resolve = probe.create_client(ResolveStud, "/arm/resolve_stud")
        r = call(probe, resolve,
                 ResolveStud.Request(stud_id="U1", decision=ResolveStud.Request.DECISION_NOT_WELDED), proc)
        assert r.success, r.message
        r = call(probe, resolve, ResolveStud.Request(stud_id="U1", decision=ResolveStud.Request.DECISION_WELDED), proc)
        assert not r.success and "not uncertain" in r.message

        action = ActionClient(probe, WeldJob, "/arm/weld_job")
        spin_until(probe, lambda: action.server_is_ready(), 20, "action server", proc)
        far = dome_targets(center=(0.15, 0.25), rings=((0.0, 1),))  # a long joint move away from home
        fut = action.send_goal_async(WeldJob.Goal(targets=[weld_target_msg(t) for t in far]))
        spin_until(probe, fut.done, 20, "goal acceptance", proc)
        handle = fut.result()
        spin_until(probe, lambda: sim.moving, 20, "the approach motion", proc)
        estop = probe.create_client(Trigger, "/arm/estop")
        spin_until(probe, estop.service_is_ready, 20, "/arm/estop", proc)
        n_stops = len(sim.commands_named("set_arm_stop"))
        t0 = time.monotonic()
        efut = estop.call_async(Trigger.Request())
        spin_until(probe, lambda: len(sim.commands_named("set_arm_stop")) > n_stops, 5, "set_arm_stop", proc)
        latency = sim.commands_named("set_arm_stop")[-1].t - t0
        print(f"\n/arm/estop service call -> set_arm_stop at the controller: {latency * 1e3:.1f} ms (over DDS)")
        assert latency < 0.5
        spin_until(probe, efut.done, 10, "estop reply", proc)
        assert efut.result().success
        rfut = handle.get_result_async()
        spin_until(probe, rfut.done, 20, "job result", proc)
        res = rfut.result().result
        assert not res.success and "e-stop" in res.message and not res.welded
        assert not sim.moving and not sim.rising_edges(1)
        spin_until(probe, lambda: states[-1].mode == ArmState.MODE_ESTOP, 5, "ESTOP mode", proc)
        fut = action.send_goal_async(WeldJob.Goal(targets=[weld_target_msg(t) for t in far]))
        spin_until(probe, fut.done, 20, "goal response", proc)
        assert not fut.result().accepted  # latched
        pub = probe.create_publisher(Bool, "/arm/estop", RELIABLE_10)
        spin_until(probe, lambda: pub.get_subscription_count() > 0, 10, "estop subscriber", proc)
        pub.publish(Bool(data=False))
        spin_until(probe, lambda: states[-1].mode != ArmState.MODE_ESTOP, 5, "e-stop release", proc)
        stop = probe.create_client(Trigger, "/arm/stop")
        assert call(probe, stop, Trigger.Request(), proc).success
    finally:
        assert proc.stop() == 0, proc.output()


# -- parameters -----------------------------------------------------------------------------------


BAD_PARAMS = [
    ("standoff_m", "-0.1", "standoff_m=-0.1: expected a number in [0.005, 0.3]"),
    ("joint_speed_pct", "1000", "joint_speed_pct=1000: expected an integer in [1, 100]"),
    ("pulse_s", ".nan", "pulse_s=nan: expected a number in [0.0, 5.0]"),
    ("tcp_port", "0", "tcp_port=0: expected an integer in [1, 65535]"),
    ("standoff_m", "1", "standoff_m=1 (int): expected a number in [0.005, 0.3]"),
    ("hand_eye_xyz_m", "[0.0,.inf,0.0]", "hand_eye_xyz_m=[0.0, inf, 0.0]: expected a list of numbers, finite"),
    ("hand_eye_xyz_m", "[]", "hand_eye_xyz_m needs 3 numbers, got []"),   # an empty list reaches rclpy "not set"
    ("workspace_min_m", "[0.0,0.0,2.0]",
     "workspace_min_m=[0.0, 0.0, 2.0] must be below workspace_max_m=[0.7, 0.7, 1.1] on every axis"),
    ("max_tool_tilt_deg", "95.0", "max_tool_tilt_deg=95.0: expected a number in [0.0, 90.0]"),
    # A 50 mm stud and the default 50 mm standoff: the retract would leave the gun on the stud's top.
    ("stud_length_mm", "50.0", "combination refused by the weld job: standoff_m=0.05 m does not pull the gun off "
     "the welded stud: the retract must clear the stud's 50 mm standing height plus stud_clearance_m=0.01 m "
     "before the gun moves sideways; expected standoff_m >= 0.06 m"),
]


def test_bad_parameters_end_the_driver_with_one_line_naming_them_and_exit_code_2(tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src" / "rm65_driver"),
                                                       str(REPO / "src" / "stud_perception"),
                                                       os.environ.get("PYTHONPATH", "")]))
    procs = [subprocess.Popen([sys.executable, "-m", "rm65_driver.driver.driver_node", "--ros-args",
                               "-p", f"journal_file:={tmp_path / f'j{i}.jsonl'}", "-p", f"{name}:={value}"],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for i, (name, value, _) in enumerate(BAD_PARAMS)]
    for proc, (name, value, expected) in zip(procs, BAD_PARAMS):
        out, _ = proc.communicate(timeout=60)
        lines = [x for x in out.splitlines() if x.strip()]
        assert proc.returncode == 2, (name, value, out)
        assert len(lines) == 1 and "Traceback" not in out, out
        assert "[FATAL]" in lines[0] and f"bad parameter {expected}" in lines[0], lines[0]


# -- a damaged journal, the driver restarted ----------------------------------------------------


def _weld_in_process(sim, journal_path, targets):
    """The first job, as a driver that crashed afterwards left it: every target welded once."""
    from rm65_driver.journal.writer import Journal
    from rm65_driver.protocol.arm_client import ArmClient
    from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
    from rm65_driver.weld.weld_job import WeldParams
    from rm65_driver.weld.weld_sequence import WeldSequence

    params = WeldParams(standoff_m=0.04, pulse_s=0.01, dwell_s=0.01, joint_speed_pct=50, linear_speed_pct=20)
    with ArmClient("127.0.0.1", sim.port) as client, Journal(journal_path) as journal:
        client.connect()
        seq = WeldSequence(client, journal, SafetyChecker(RM65Kinematics(), SafetyLimits(), params.tool_T), params)
        assert seq.run(targets).success


def _random_bytes(path):
    path.write_bytes(np.random.default_rng(14).integers(0, 256, 4096, dtype=np.uint8).tobytes())


def _nul_block(path):  # over the third stud's two lines (records 5 and 6)
    data = path.read_bytes()
    lines = data.split(b"\n")
    start = sum(len(x) + 1 for x in lines[:4])
    n = len(lines[4]) + len(lines[5]) + 1
    path.write_bytes(data[:start] + b"\0" * n + data[start + n:])


def _torn_tail(path):  # power cut while the next stud's 'started' was being written
    with open(path, "ab") as f:
        f.write(b'{"seq":17,"event":"started","stud":"S0008","job":"2026')


def _run_job(probe, action, targets, proc, resume=True):
    fut = action.send_goal_async(WeldJob.Goal(targets=[weld_target_msg(t) for t in targets], resume=resume))
    spin_until(probe, fut.done, 20, "goal response", proc)
    handle = fut.result()
    assert handle.accepted
    rfut = handle.get_result_async()
    spin_until(probe, rfut.done, 60, "job result", proc)
    return rfut.result().result


@pytest.mark.parametrize("damage", ["random_bytes", "nul_block", "torn_tail"])
def test_damaged_journal_then_driver_restart_never_repeats_a_weld(sim, probe, tmp_path, damage):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from stud_welding_msgs.srv import ResolveJournal

    journal_path = tmp_path / "journal.jsonl"
    targets = dome_targets(rings=((0.0, 1), (0.05, 7)))
    _weld_in_process(sim, journal_path, targets)
    assert len(sim.rising_edges(1)) == 8
    {"random_bytes": _random_bytes, "nul_block": _nul_block, "torn_tail": _torn_tail}[damage](journal_path)

    proc = NodeProc(sim.port, tmp_path, pulse_s=0.01, dwell_s=0.01, standoff_m=0.04, state_rate_hz=20.0,
                    joint_speed_pct=50, linear_speed_pct=20)
    try:
        states, diags = [], []
        probe.create_subscription(ArmState, "/arm/state", states.append, RELIABLE_10)
        probe.create_subscription(DiagnosticArray, "/diagnostics", diags.append, RELIABLE_10)
        action = ActionClient(probe, WeldJob, "/arm/weld_job")
        spin_until(probe, lambda: states and states[-1].connected and action.server_is_ready(), 30, "driver", proc)
        extra = dome_targets(rings=((0.10, 1),))[0]
        extra = type(extra)("S0008", extra.position, extra.normal)
        if damage == "torn_tail":
            # tolerated: no FAULT; the torn record's stud is uncertain and not welded without a decision
            assert states[-1].mode == ArmState.MODE_IDLE, states[-1].message
            res = _run_job(probe, action, targets + [extra], proc)
            assert list(res.welded) == [t.stud_id for t in targets] and list(res.failed) == ["S0008"]
            assert "operator decision" in res.messages[-1]
            assert len(sim.rising_edges(1)) == 8
            resolve = probe.create_client(ResolveStud, "/arm/resolve_stud")
            r = call(probe, resolve, ResolveStud.Request(stud_id="S0008",
                                                         decision=ResolveStud.Request.DECISION_NOT_WELDED), proc)
            assert r.success, r.message
            res = _run_job(probe, action, targets + [extra], proc)
            assert res.success and len(res.welded) == 9 and len(sim.rising_edges(1)) == 9
            return

        spin_until(probe, lambda: states[-1].mode == ArmState.MODE_FAULT, 10, "FAULT", proc)
        msg = states[-1].message
        where = "lines 1-" if damage == "random_bytes" else "line 5 (not JSON"
        assert f"weld journal {journal_path} is damaged: {where}" in msg, msg
        spin_until(probe, lambda: any(s.level == DiagnosticStatus.ERROR and "weld journal FAULT" in s.message
                                      for d in diags for s in d.status), 10, "/diagnostics ERROR", proc)
        res = _run_job(probe, action, targets, proc)  # refused with the reason, nothing moves
        assert not res.success and "weld journal FAULT" in res.message and str(journal_path) in res.message
        assert not res.welded and len(sim.rising_edges(1)) == 8

        resolve = probe.create_client(ResolveJournal, "/arm/resolve_journal")
        act = (ResolveJournal.Request.ACTION_LOAD_BACKUP if damage == "random_bytes"
               else ResolveJournal.Request.ACTION_ACCEPT_INTACT)
        r = call(probe, resolve, ResolveJournal.Request(action=act, note="test"), proc)
        assert r.success, r.message
        spin_until(probe, lambda: states[-1].mode != ArmState.MODE_FAULT, 10, "FAULT cleared", proc)
        assert list(tmp_path.glob("journal.jsonl.corrupt-*"))
        res = _run_job(probe, action, targets, proc)
        if damage == "random_bytes":  # the mirror loaded: every stud known welded
            assert res.success and list(res.welded) == [t.stud_id for t in targets], res.message
        else:  # accepted the two studs before the NUL block; the rest (the mirror knows them) uncertain
            assert list(res.welded) == ["S0000", "S0001"] and list(res.failed) == [t.stud_id for t in targets[2:]]
        assert len(sim.rising_edges(1)) == 8  # no stud welded twice, counted at the simulator
        assert set(welds_per_stud(sim, targets).values()) == {1}
    finally:
        assert proc.stop() == 0, proc.output()

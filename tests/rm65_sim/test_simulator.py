"""The simulator speaks the documented protocol: checked with a raw socket, byte by byte."""
from __future__ import annotations

import socket
import struct
import threading
import time

import numpy as np
import pytest

from rm65_driver.kinematics.rm65 import RM65Kinematics
from rm65_driver.protocol import messages as P
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator, main
from rm65_testing import wait_for


class Raw:
    """A bare TCP peer: send bytes or dicts, read decoded messages."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=2.0)
        self.dec = P.FrameDecoder()
        self.inbox: list[dict] = []

    def send(self, msg) -> None:
        self.sock.sendall(msg if isinstance(msg, bytes) else P.encode(msg))

    def recv(self, n: int = 1, timeout: float = 2.0) -> list[dict]:
        end = time.monotonic() + timeout
        while len(self.inbox) < n and time.monotonic() < end:
            self.sock.settimeout(max(0.01, end - time.monotonic()))
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                break
            except OSError:  # reset by the peer: treated as closed
                break
            if not data:
                break
            self.inbox += self.dec.feed(data)
        out, self.inbox = self.inbox[:n], self.inbox[n:]
        return out

    def ask(self, msg, n: int = 1, timeout: float = 2.0) -> list[dict]:
        self.send(msg)
        return self.recv(n, timeout)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def raw(sim):
    r = Raw(sim.port)
    yield r
    r.close()


def test_handshake_queries_of_the_official_sdk_are_answered(raw):
    for name in P.HANDSHAKE_COMMANDS:
        [reply] = raw.ask({"command": name})
        assert P.reply_tag(reply) in P.expected_reply_tags(name), (name, reply)
    # fields the SDK requires (docs/RM65_PROTOCOL.md §2)
    [info] = raw.ask({"command": "get_arm_software_info"})
    assert info["Product_version"].startswith("RM65-B")
    [push] = raw.ask({"command": "get_realtime_push"})
    assert {"custom", "cycle", "enable", "ip", "port"} <= set(push)
    [tool] = raw.ask({"command": "get_current_tool_frame"})
    assert {"tool_name", "pose", "payload", "position"} <= set(tool)
    [dh] = raw.ask({"command": "get_DH_data"})
    assert dh["joint_6"] == [90000, 0, 144000, 0] and dh["joint_3"] == [0, 256000, 0, 90000]
    [mx] = raw.ask({"command": "get_joint_max_pos"})
    assert mx["max_pos"] == [178000, 130000, 135000, 178000, 128000, 360000]


def test_movej_ack_then_arrival_and_the_state_follows(raw, sim):
    q = np.radians([5, -25, -95, 3, -55, 10])
    msgs = raw.ask(P.movej(q, 50), n=2)
    assert msgs[0] == {"command": "movej", "receive_state": True}
    assert msgs[1] == {"state": "current_trajectory_state", "trajectory_state": True, "device": 0,
                       "trajectory_connect": 0}
    [st] = raw.ask(P.get_current_arm_state())
    r = P.parse_arm_state(st)
    np.testing.assert_allclose(r.joints_rad, q, atol=2e-5)
    assert r.error_codes == () and st["arm_state"]["err"] == [0]
    T = RM65Kinematics().fk(r.joints_rad)
    np.testing.assert_allclose(r.pose[:3], T[:3, 3], atol=2e-6)


def test_movel_moves_in_a_straight_line_and_movej_p_reaches_the_pose(raw, sim):
    [st] = raw.ask(P.get_current_arm_state())
    pose = P.parse_arm_state(st).pose
    goal = pose.copy()
    goal[2] -= 0.04
    raw.send(P.movel(goal, 30))
    zs = []
    [ack] = raw.recv(1)
    assert ack.get("receive_state") is True, ack
    while not raw.inbox:
        zs.append(sim.tcp_pose()[:3, 3].copy())
        raw.inbox += raw.dec.feed(raw.sock.recv(65536)) if _readable(raw.sock) else []
    assert raw.recv(1)[0]["trajectory_state"] is True
    zs = np.array(zs)
    np.testing.assert_allclose(zs[:, :2], np.tile(pose[:2], (len(zs), 1)), atol=2e-4)
    goal2 = goal.copy()
    goal2[1] += 0.05
    msgs = raw.ask(P.movej_p(goal2, 40), n=2)
    assert msgs[0]["receive_state"] and msgs[1]["trajectory_state"]
    np.testing.assert_allclose(sim.tcp_pose()[:3, 3], goal2[:3], atol=2e-6)


def _readable(sock) -> bool:
    import select
    return bool(select.select([sock], [], [], 0.002)[0])


def test_motion_takes_scaled_real_time():
    with ArmSimulator(port=0, config=SimulatorConfig(time_scale=0.2, initial_joints_deg=(0, 0, 90, 0, 90, 0))) as s:
        r = Raw(s.port)
        t0 = time.monotonic()
        # J1 90 deg at 50 % of 180 deg/s and of 600 deg/s^2: 1.0 s cruising + 0.3 s to speed up and
        # slow down = 1.3 s simulated -> 0.26 s real (a move without acceleration would take 0.2)
        msgs = r.ask(P.movej(np.radians([90, 0, 90, 0, 90, 0]), 50), n=2)
        dt = time.monotonic() - t0
        assert msgs[1]["trajectory_state"] is True
        assert 0.25 < dt < 0.6
        r.close()


def test_out_of_limit_and_unreachable_targets_are_refused_with_error_codes(raw, sim):
    [ack] = raw.ask(P.movej(np.radians([0, 0, 140, 0, 0, 0]), 20))
    assert ack == {"command": "movej", "receive_state": False}
    [st] = raw.ask(P.get_current_arm_state())
    assert st["arm_state"]["err"] == [0x1002]
    t0 = time.monotonic()
    [ack] = raw.ask(P.movej_p([0.9, 0, 0.1, np.pi, 0, 0], 20))
    assert ack["receive_state"] is False and time.monotonic() - t0 < 0.5  # within the SDK's reply timeout
    [st] = raw.ask(P.get_current_arm_state())
    assert st["arm_state"]["err"] == [0x1003]
    [ack] = raw.ask(P.movel([0.9, 0, 0.1, np.pi, 0, 0], 20))
    assert ack["receive_state"] is False
    assert not sim.moving and not sim.motion_log
    # the next accepted motion clears the error (DOCS)
    raw.ask(P.movej(sim.joints, 20), n=2)
    [st] = raw.ask(P.get_current_arm_state())
    assert st["arm_state"]["err"] == [0]


@pytest.mark.parametrize("fmt, key", [("scalar", "err"), ("arm_sys", "arm_err")])
def test_older_error_formats_are_configurable(fmt, key):
    with ArmSimulator(port=0, config=SimulatorConfig(err_format=fmt)) as s:
        r = Raw(s.port)
        s.set_error(0x100D)
        [st] = r.ask(P.get_current_arm_state())
        assert key in st["arm_state"] and "err" not in st["arm_state"] or fmt == "scalar"
        assert P.parse_arm_state(st).error_codes == (0x100D,)
        r.close()


def test_pretty_printed_requests_and_replies():
    with ArmSimulator(port=0, config=SimulatorConfig(pretty_replies=True)) as s:
        r = Raw(s.port)
        r.send(P.encode(P.get_current_arm_state(), pretty=True)
               + P.encode({"command": "get_joint_degree"}, pretty=True))
        raw_bytes = b""
        end = time.monotonic() + 2
        while raw_bytes.count(b"\r\n") < 2 and time.monotonic() < end:
            raw_bytes += r.sock.recv(65536)
        assert b"\n\t" in raw_bytes  # really pretty
        msgs = P.FrameDecoder().feed(raw_bytes)
        assert [P.reply_tag(m) for m in msgs] == ["current_arm_state", "joint_degree"]
        r.close()


def test_several_commands_in_one_write_and_split_writes(raw):
    raw.send(P.encode(P.get_IO_output()) + P.encode(P.get_tool_IO_state()) + b'{"command":"get_joint_')
    time.sleep(0.02)
    raw.send(b'degree"}\r\n')
    tags = [P.reply_tag(m) for m in raw.recv(3)]
    assert tags == ["IO_output_state", "tool_IO_state", "joint_degree"]


def test_garbage_line_is_skipped_and_the_connection_survives(raw):
    raw.send(b"hello controller\r\n")
    [reply] = raw.ask(P.get_joint_degree())
    assert reply["state"] == "joint_degree"


def test_stop_pause_continue(raw, sim):
    raw.send(P.movej(np.radians([60, -30, -100, 0, -50, 0]), 1))  # slow: 60 deg at 1.8 deg/s
    assert raw.recv(1)[0]["receive_state"]
    assert wait_for(lambda: sim.joints[0] > 0.0005)
    [ack] = raw.ask(P.set_arm_pause())
    assert ack == {"command": "set_arm_pause", "arm_pause": True}
    q1 = sim.joints[0]
    time.sleep(0.05)
    assert sim.joints[0] == q1
    [traj] = raw.ask(P.get_arm_current_trajectory())
    assert traj["type"] == "movej"
    [ack] = raw.ask(P.set_arm_continue())
    assert ack == {"command": "set_arm_continue", "arm_continue": True}
    assert wait_for(lambda: sim.joints[0] > q1)
    msgs = raw.ask(P.set_arm_stop(), n=2)
    assert msgs[0] == {"command": "set_arm_stop", "arm_stop": True}
    assert msgs[1]["state"] == "current_trajectory_state" and msgs[1]["trajectory_state"] is False
    q2 = sim.joints[0]
    time.sleep(0.05)
    assert sim.joints[0] == q2 and not sim.moving
    [traj] = raw.ask(P.get_arm_current_trajectory())
    assert traj["type"] == "none"
    [ack] = raw.ask(P.set_arm_slow_stop())
    assert ack == {"command": "set_arm_slow_stop", "arm_slow_stop": True}


def test_tool_and_work_frames_change_the_reported_pose(raw, sim):
    [st0] = raw.ask(P.get_current_arm_state())
    p0 = P.parse_arm_state(st0).pose
    assert raw.ask(P.set_manual_tool_frame("weld", [0, 0, 0.12, 0, 0, 0], 1.0, [0, 0, 0.05]))[0]["manual_tool_frame"]
    assert raw.ask(P.set_change_tool_frame("weld"))[0]["change_tool_frame"]
    [tf] = raw.ask(P.get_current_tool_frame())
    assert tf["tool_name"] == "weld" and tf["pose"] == [0, 0, 120000, 0, 0, 0] and tf["payload"] == 1000
    [st1] = raw.ask(P.get_current_arm_state())
    p1 = P.parse_arm_state(st1).pose
    np.testing.assert_allclose(p1[2], p0[2] - 0.12, atol=2e-6)  # the tool points down
    assert raw.ask(P.set_manual_work_frame("table", [0.3, 0, 0, 0, 0, 0]))[0]["manual_work_frame"]
    assert raw.ask(P.set_change_work_frame("table"))[0]["change_work_frame"]
    [wf] = raw.ask(P.get_current_work_frame())
    assert wf == {"state": "current_work_frame", "frame_name": "table", "pose": [300000, 0, 0, 0, 0, 0]}
    p2 = P.parse_arm_state(raw.ask(P.get_current_arm_state())[0]).pose
    np.testing.assert_allclose(p2[0], p1[0] - 0.3, atol=2e-6)
    assert raw.ask(P.set_change_tool_frame("nope"))[0]["change_tool_frame"] is False
    assert P.parse_arm_state(raw.ask(P.get_current_arm_state())[0]).error_codes == (0x100F,)
    [names] = raw.ask({"command": "get_total_tool_frame"})
    assert "weld" in names["tool_names"]


def test_io_outputs_need_output_mode_and_are_recorded_with_the_tcp_pose(raw, sim):
    assert raw.ask(P.set_DO_state(1, 1))[0] == {"command": "set_DO_state", "set_state": False}
    assert raw.ask(P.set_IO_mode(1, 1))[0] == {"command": "set_IO_mode", "set_state": True}
    assert raw.ask(P.set_DO_state(1, 1))[0]["set_state"] is True
    assert raw.ask(P.get_IO_state(1))[0] == {"state": "IO_state", "IO_Num": 1, "IO_Mode": 1, "IO_state": 1}
    assert raw.ask(P.get_IO_output())[0]["DO"] == [1, 0, 0, 0]
    assert raw.ask(P.set_DO_state(1, 0))[0]["set_state"] is True
    assert raw.ask(P.set_DO_state(5, 1))[0]["set_state"] is False
    assert raw.ask(P.set_tool_IO_mode(2, 1))[0]["set_state"] is True
    assert raw.ask(P.set_tool_voltage(3))[0] == {"command": "set_tool_voltage", "state": True}
    assert raw.ask(P.set_tool_DO_state(2, 1))[0]["set_state"] is True
    assert raw.ask(P.get_tool_IO_state())[0] == {"state": "tool_IO_state", "IO_Mode": [0, 1], "IO_State": [0, 1]}
    [edge] = sim.rising_edges(1)
    np.testing.assert_allclose(edge.tcp_pose, sim.tcp_pose(), atol=1e-9)
    assert len(sim.rising_edges(2, tool=True)) == 1
    assert [e.value for e in sim.do_events] == [1, 0, 1]


def test_fault_drop_after_n_commands_and_refuse_connections(sim):
    r = Raw(sim.port)
    sim.drop_after_commands(2)
    assert r.ask(P.get_joint_degree())
    assert r.ask(P.get_joint_degree())  # replied, then dropped
    assert r.recv(1, timeout=0.3) == []
    assert wait_for(lambda: sim.client_count == 0)
    sim.refuse_connections(1)
    r2 = Raw(sim.port)
    assert r2.ask(P.get_joint_degree()) == []
    r3 = Raw(sim.port)
    assert r3.ask(P.get_joint_degree())[0]["state"] == "joint_degree"
    for x in (r, r2, r3):
        x.close()


def test_fault_controller_errors_stall_and_mid_motion_drop(sim, raw):
    sim.fail_next("movej", 0x1001)
    assert raw.ask(P.movej(sim.joints, 20))[0]["receive_state"] is False
    assert P.parse_arm_state(raw.ask(P.get_current_arm_state())[0]).error_codes == (0x1001,)
    sim.fail_next("movej", 0x100D, mode="trajectory")
    q = np.radians([20, -30, -100, 0, -50, 0])
    msgs = raw.ask(P.movej(q, 50), n=2)
    assert msgs[0]["receive_state"] is True and msgs[1]["trajectory_state"] is False
    assert P.parse_arm_state(raw.ask(P.get_current_arm_state())[0]).error_codes == (0x100D,)
    sim.stall_next_motion(0.5)
    assert raw.ask(P.movej(q, 50))[0]["receive_state"]
    assert raw.recv(1, timeout=0.3) == []  # never arrives
    assert raw.ask(P.get_arm_current_trajectory())[0]["type"] == "movej"
    raw.ask(P.set_arm_stop(), n=2)
    sim.drop_mid_motion(fraction=0.3)
    raw.send(P.movej(np.radians([-20, -30, -100, 0, -50, 0]), 50))
    assert raw.recv(1)[0]["receive_state"]
    assert raw.recv(1, timeout=1.0) == []  # connection gone before arrival
    assert wait_for(lambda: not sim.moving)  # the controller finishes its trajectory anyway
    np.testing.assert_allclose(np.degrees(sim.joints[0]), -20, atol=1e-3)
    sim.fail_next("get_joint_degree", 0, mode="no_reply")
    r2 = Raw(sim.port)
    assert r2.ask(P.get_joint_degree(), timeout=0.3) == []  # swallowed
    assert r2.ask(P.get_joint_degree())[0]["state"] == "joint_degree"
    r2.close()


def test_commands_are_recorded_with_arrival_times(raw, sim):
    t0 = time.monotonic()
    raw.ask(P.get_joint_degree())
    rec = sim.commands_named("get_joint_degree")[-1]
    assert t0 <= rec.t <= time.monotonic()


def test_cli_rejects_a_busy_port(capsys):
    with ArmSimulator(port=0) as s:
        assert main(["--port", str(s.port)]) == 2
    assert "cannot start" in capsys.readouterr().err


@pytest.mark.parametrize("raw_msg, code", [
    (P.encode(P.movel([1e300, 0.0, 0.3, 3.14, 0.0, 0.0], 20)), 0x1003),
    (P.encode(P.movej_p([1e300, 0.0, 0.3, 3.14, 0.0, 0.0], 20)), 0x1003),
    (b'{"command":"movel","v":20,"pose":[' + b"9" * 400 + b',0,0,0,0,0],"trajectory_connect":0}\r\n', 0x1003),
    (b'{"command":"movel","v":20,"pose":[NaN,0,300000,3140,0,0],"trajectory_connect":0}\r\n', 0x1003),
    (b'{"command":"movej_p","v":20,"pose":[1e400,0,0,0,0,0],"trajectory_connect":0}\r\n', 0x1003),
    (b'{"command":"movel","v":20,"pose":[300000,0,200000,1e300,0,0],"trajectory_connect":0}\r\n', 0x1003),
    (P.encode(P.movel([2.0, 0.0, 0.3, 3.14, 0.0, 0.0], 20)), 0x1003),  # finite, far out of reach
    (b'{"command":"movej","v":20,"joint":[' + b"9" * 400 + b',0,0,0,0,0],"trajectory_connect":0}\r\n', 0x1002),
    (b'{"command":"movej","v":20,"joint":[Infinity,0,0,0,0,0],"trajectory_connect":0}\r\n', 0x1002),
], ids=["movel-1e300m", "movej_p-1e300m", "movel-400-digits", "movel-NaN", "movej_p-1e400", "movel-1e300rad",
        "movel-2m-away", "movej-400-digits", "movej-Infinity"])
def test_absurd_targets_are_refused_like_unreachable_ones_and_the_connection_survives(raw, sim, raw_msg, code):
    q = sim.joints
    [reply] = raw.ask(raw_msg)
    assert reply["receive_state"] is False
    assert P.parse_arm_state(raw.ask(P.get_current_arm_state())[0]).error_codes == (code,)
    assert raw.ask(P.get_joint_degree())[0]["state"] == "joint_degree"  # same connection, still served
    assert not sim.moving and np.allclose(sim.joints, q)


def test_200_simultaneous_connections_open_without_a_retry(sim):
    """A short listen backlog drops the SYNs of a burst of clients, which then retry after 1, 3, 7 s
    (20 s for 200 clients was seen). No client may need a retransmission (Linux TCP_INFO)."""
    socks, errors = [], []
    lock = threading.Lock()

    def one():
        try:
            s = socket.create_connection(("127.0.0.1", sim.port), timeout=30)
            s.settimeout(30)
            s.sendall(P.encode(P.get_joint_degree()))
            assert b"joint_degree" in s.recv(65536)
            with lock:
                socks.append(s)
        except (OSError, AssertionError) as exc:
            with lock:
                errors.append(exc)

    t0 = time.monotonic()
    threads = [threading.Thread(target=one) for _ in range(200)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    elapsed = time.monotonic() - t0
    try:
        assert not errors and len(socks) == 200
        assert sim.client_count == 200
        if hasattr(socket, "TCP_INFO"):
            # struct tcp_info: 8 bytes of u8 fields, then u32s; tcpi_total_retrans is the 24th
            retrans = [struct.unpack_from("I", s.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 104), 100)[0]
                       for s in socks]
            assert sum(1 for r in retrans if r) == 0, f"{sum(1 for r in retrans if r)} clients had to retransmit"
        assert elapsed < 10.0
    finally:
        for s in socks:
            s.close()
    assert wait_for(lambda: sim.client_count == 0, 10)

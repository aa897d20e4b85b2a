"""The simulated rail (expansion joint, device 4) speaks RealMan's protocol: checked over a raw socket."""
from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from rm65_driver.protocol import messages as P
from rm65_driver.rail.axis import RailAxis, RailMode
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator
from rm65_testing import HOME_DEG, wait_for
from stud_common.frames import RailDeviation, carriage_in_world

AXIS = RailAxis(length_m=6.0, pos_unit_m=1e-6, max_speed_m_s=0.5, accel_m_s2=0.5)
SDK_STATE_KEYS = {"state", "pos", "current", "err_flag", "en_flag", "mode", "joint_id"}


class Peer:
    """A bare TCP client: send dicts, collect every decoded message (replies and arrivals)."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=2.0)
        self.dec = P.FrameDecoder()
        self.inbox: list[dict] = []

    def send(self, msg: dict) -> None:
        self.sock.sendall(P.encode(msg))

    def pump(self, timeout: float = 0.01) -> None:
        self.sock.settimeout(timeout)
        try:
            data = self.sock.recv(65536)
        except (socket.timeout, OSError):
            return
        self.inbox += self.dec.feed(data)

    def wait(self, pred, timeout: float = 5.0) -> dict:
        """The first message (removed from the inbox) for which ``pred`` holds."""
        end = time.monotonic() + timeout
        while True:
            for i, m in enumerate(self.inbox):
                if pred(m):
                    return self.inbox.pop(i)
            if time.monotonic() > end:
                raise AssertionError(f"no such message within {timeout} s; inbox {self.inbox}")
            self.pump(0.02)

    def ask(self, msg: dict, tag: str) -> dict:
        self.send(msg)
        return self.wait(lambda m: P.reply_tag(m) == tag)

    def arrivals(self) -> list[dict]:
        self.pump(0.05)
        out = [m for m in self.inbox if m.get("state") == P.TRAJECTORY_STATE]
        self.inbox = [m for m in self.inbox if m not in out]
        return out

    def state(self) -> dict:
        return self.ask({"command": "expand_get_state"}, "expand_state")

    def close(self) -> None:
        self.sock.close()


def _sim(time_scale=0.02, **kw) -> ArmSimulator:
    kw.setdefault("rail_axis", AXIS)
    config = SimulatorConfig(time_scale=time_scale, initial_joints_deg=HOME_DEG, **kw)
    return ArmSimulator(port=0, config=config).start()


@pytest.fixture
def rail_sim():
    s = _sim()
    yield s
    s.stop()


@pytest.fixture
def peer(rail_sim):
    p = Peer(rail_sim.port)
    yield p
    p.close()


def is_arrival(device):
    return lambda m: m.get("state") == P.TRAJECTORY_STATE and m.get("device") == device


def test_a_position_move_is_acknowledged_then_arrives_and_the_state_reports_the_commanded_count(rail_sim, peer):
    st = peer.state()
    assert set(st) == SDK_STATE_KEYS and all(isinstance(st[k], int) for k in SDK_STATE_KEYS - {"state"})
    assert st["pos"] == 0 and st["mode"] == RailMode.IDLE and st["en_flag"] == 1
    assert peer.ask({"command": "expand_set_pos", "pos": 1_250_000, "speed": 40}, "expand_set_pos") == \
        {"command": "expand_set_pos", "set_pos_state": True}
    arrival = peer.wait(is_arrival(4))
    assert arrival == {"state": "current_trajectory_state", "device": 4, "trajectory_state": True,
                       "trajectory_connect": 0}
    st = peer.state()
    assert st["pos"] == 1_250_000 and st["mode"] == RailMode.IDLE
    assert rail_sim.rail.position_m == pytest.approx(1.25)
    # back toward zero, with the SDK's optional block field
    peer.send({"command": "expand_set_pos", "pos": 300_000, "speed": 100, "block": True})
    assert peer.wait(is_arrival(4))["trajectory_state"] is True
    assert peer.state()["pos"] == 300_000


def test_the_move_runs_in_scaled_real_time_with_mode_2_or_4_while_moving():
    sim = _sim(time_scale=0.25)
    peer = Peer(sim.port)
    try:
        peer.send({"command": "expand_set_pos", "pos": 1_000_000, "speed": 50})
        seen = []
        while not any(m.get("device") == 4 for m in peer.inbox if m.get("state") == P.TRAJECTORY_STATE):
            st = peer.state()
            seen.append((st["mode"], st["pos"]))
        moving = [pos for mode, pos in seen if mode == RailMode.POSITION_POSITIVE]
        assert any(0 < p < 1_000_000 for p in moving), seen
        assert moving == sorted(moving)  # forward only, no overshoot
        assert set(mode for mode, _ in seen) <= {RailMode.POSITION_POSITIVE, RailMode.IDLE}
        peer.send({"command": "expand_set_pos", "pos": 400_000, "speed": 50})
        assert wait_for(lambda: sim.rail.mode == RailMode.POSITION_NEGATIVE, 2.0)
        assert peer.wait(is_arrival(4))["trajectory_state"] is True
    finally:
        peer.close()
        sim.stop()


def test_move_duration_is_the_axis_trapezoid_at_the_speed_percentage():
    # 1 m at 50 %: 0.25 m/s and 0.25 m/s^2 -> 1 s up, 3 s cruise, 1 s down
    assert AXIS.move_time_s(1.0, 50) == pytest.approx(5.0)
    # short move: a triangle, 2 sqrt(L / a)
    assert AXIS.move_time_s(0.01, 100) == pytest.approx(2 * np.sqrt(0.01 / 0.5))


@pytest.mark.parametrize("request_", [
    {"pos": 6_000_001, "speed": 50},        # beyond the travel
    {"pos": -1, "speed": 50},               # before its zero
    {"pos": 1000, "speed": 0},              # a position move needs 1..100 %
    {"pos": 1000, "speed": 101},
    {"pos": 1000.5, "speed": 50},           # not a count
    {"pos": "1000", "speed": 50},
    {"pos": 1e300, "speed": 50},
    {"speed": 50},                          # no target
])
def test_out_of_range_or_malformed_targets_are_refused_with_false_and_nothing_moves(rail_sim, peer, request_):
    reply = peer.ask({"command": "expand_set_pos", **request_}, "expand_set_pos")
    assert reply == {"command": "expand_set_pos", "set_pos_state": False}
    assert peer.arrivals() == [] and not rail_sim.rail.moving and rail_sim.rail.position_m == 0.0


def test_the_far_end_of_the_travel_is_accepted(rail_sim, peer):
    assert peer.ask({"command": "expand_set_pos", "pos": 6_000_000, "speed": 100}, "expand_set_pos")["set_pos_state"]
    assert peer.wait(is_arrival(4), timeout=10)["trajectory_state"] is True
    assert peer.state()["pos"] == 6_000_000


def test_a_second_move_while_moving_is_refused_and_the_first_still_arrives():
    sim = _sim(time_scale=0.5)
    peer = Peer(sim.port)
    try:
        assert peer.ask({"command": "expand_set_pos", "pos": 500_000, "speed": 50}, "expand_set_pos")["set_pos_state"]
        assert peer.ask({"command": "expand_set_pos", "pos": 100_000, "speed": 50},
                        "expand_set_pos")["set_pos_state"] is False
        assert peer.wait(is_arrival(4))["trajectory_state"] is True
        assert peer.state()["pos"] == 500_000
    finally:
        peer.close()
        sim.stop()


@pytest.mark.parametrize("stop", ["set_arm_stop", "set_arm_slow_stop", "expand_set_speed"])
def test_a_stop_ends_the_move_with_a_false_arrival_where_the_carriage_is(stop):
    sim = _sim(time_scale=0.5)
    peer = Peer(sim.port)
    try:
        peer.send({"command": "expand_set_pos", "pos": 3_000_000, "speed": 100})
        assert wait_for(lambda: sim.rail.position_m > 0.02, 5.0)
        msg = {"command": stop, "speed": 0} if stop == "expand_set_speed" else {"command": stop}
        peer.send(msg)
        arrival = peer.wait(is_arrival(4))
        assert arrival["trajectory_state"] is False and arrival["trajectory_connect"] == 0
        key = P.RESULT_KEY[stop]
        assert peer.wait(lambda m: m.get("command") == stop)[key] is True
        st = peer.state()
        assert st["mode"] == RailMode.IDLE and 20_000 < st["pos"] < 3_000_000
        time.sleep(0.1)
        assert peer.state()["pos"] == st["pos"]  # it stays stopped
        assert [ok for _, ok in sim.rail.arrivals] == [False]
    finally:
        peer.close()
        sim.stop()


def test_a_jog_moves_at_its_speed_stops_on_zero_and_halts_at_the_end_of_the_travel():
    sim = _sim(time_scale=0.1)
    peer = Peer(sim.port)
    try:
        assert peer.ask({"command": "expand_set_speed", "speed": 60},
                        "expand_set_speed") == {"command": "expand_set_speed", "set_speed_state": True}
        assert wait_for(lambda: sim.rail.position_m > 0.05, 5.0)
        assert peer.state()["mode"] == RailMode.SPEED_POSITIVE
        assert peer.ask({"command": "expand_set_speed", "speed": 0}, "expand_set_speed")["set_speed_state"]
        assert peer.state()["mode"] == RailMode.IDLE
        assert peer.arrivals() == []  # a jog has no arrival message
        assert peer.ask({"command": "expand_set_speed", "speed": -100}, "expand_set_speed")["set_speed_state"]
        assert wait_for(lambda: not sim.rail.moving, 10.0)  # ran into the rail's zero
        assert sim.rail.position_m == 0.0 and peer.state()["mode"] == RailMode.IDLE
        for bad in (101, -101, 2.5, None):
            reply = peer.ask({"command": "expand_set_speed", "speed": bad}, "expand_set_speed")
            assert reply["set_speed_state"] is False
    finally:
        peer.close()
        sim.stop()


def test_arm_and_rail_arrivals_carry_their_devices_and_interleave(rail_sim, peer):
    q = np.radians(HOME_DEG) + np.radians([10, 0, 0, 0, 0, 0])
    peer.send({"command": "expand_set_pos", "pos": 2_000_000, "speed": 30})
    peer.send(P.movej(q, 20))
    assert peer.wait(is_arrival(0))["trajectory_state"] is True
    assert peer.wait(is_arrival(4), timeout=10)["trajectory_state"] is True
    np.testing.assert_allclose(rail_sim.joints, q, atol=1e-9)


def test_a_controller_without_the_axis_refuses_and_reports_it_disabled():
    sim = ArmSimulator(port=0, config=SimulatorConfig(time_scale=0.02)).start()
    peer = Peer(sim.port)
    try:
        assert peer.ask({"command": "expand_set_pos", "pos": 0, "speed": 50},
                        "expand_set_pos")["set_pos_state"] is False
        assert peer.ask({"command": "expand_set_speed", "speed": 10},
                        "expand_set_speed")["set_speed_state"] is False
        st = peer.state()
        assert st["en_flag"] == 0 and st["mode"] == 0
        np.testing.assert_array_equal(sim.rail.true_base_in_world(), np.eye(4))
    finally:
        peer.close()
        sim.stop()


def test_the_true_base_carries_the_rail_deviation_the_reported_pos_does_not():
    dev = RailDeviation(scale_ppm=800.0, offset_m=0.004, yaw_urad_per_m=150.0)
    sim = _sim(rail_deviation=dev, rail_mount_xyz_m=(0.1, -0.05, 0.3))
    peer = Peer(sim.port)
    try:
        peer.send({"command": "expand_set_pos", "pos": 5_000_000, "speed": 100})
        assert peer.wait(is_arrival(4), timeout=10)["trajectory_state"]
        assert peer.state()["pos"] == 5_000_000  # the encoder: no idea of its scale error
        T = sim.rail.true_base_in_world()
        # along the rail: 5 m x (1 + 800 ppm) + 4 mm = 5.008 m of a curve, then the mount turned with it
        s = 5.0 * (1 + 800e-6) + 0.004
        heading = 150e-6 * s
        assert np.arctan2(T[1, 0], T[0, 0]) == pytest.approx(heading, abs=1e-12)
        expected = carriage_in_world(5.0, dev)[:3, :3] @ [0.1, -0.05, 0.3] + [s - 150e-6 ** 2 * s ** 3 / 6,
                                                                             150e-6 * s ** 2 / 2, 0.0]
        np.testing.assert_allclose(T[:3, 3], expected, atol=1e-9)
        assert np.linalg.norm(T[:3, 3] - [5.1, -0.05, 0.3]) > 0.008  # not where the cell believes it
        # a trigger edge records where the tool truly was
        peer.send(P.set_IO_mode(1, 1))
        peer.send(P.set_DO_state(1, 1))
        assert wait_for(lambda: sim.rising_edges(1), 2.0)
        [edge] = sim.rising_edges(1)
        np.testing.assert_allclose(edge.true_world_position, (T @ sim.tcp_pose())[:3, 3], atol=1e-12)
    finally:
        peer.close()
        sim.stop()


def test_simulator_command_line_refuses_a_bad_rail(capsys):
    from rm65_sim.simulator import main
    assert main(["--port", "-1", "--rail-length-m", "-2"]) == 2
    assert "rail length_m=-2.0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--rail-length-m", "2", "--rail-mount-xyz-m=[0.1, 0.2]"])
    assert "is not three numbers x,y,z" in capsys.readouterr().err


def test_simulator_command_line_runs_a_rail(tmp_path):
    """`ros2 run rm65_driver simulator` with a rail, its mount written as a cell var renders a list."""
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    src = Path(__file__).resolve().parents[2] / "src"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(src / "rm65_sim"), str(src / "rm65_driver"),
                                                       str(src / "stud_common"), os.environ.get("PYTHONPATH", "")]))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "rm65_sim.simulator", "--port", str(port), "--time-scale", "0.02",
                             "--rail-length-m", "3", "--rail-mount-xyz-m=[0.0, 0.0, 0.1]", "--true-rail-offset-m",
                             "0.002"], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert "rail of 3 m" in proc.stdout.readline()
        peer = Peer(port)
        assert peer.ask({"command": "expand_set_pos", "pos": 3_000_000, "speed": 100},
                        "expand_set_pos")["set_pos_state"]
        assert peer.wait(is_arrival(4), timeout=10)["trajectory_state"] is True
        assert peer.ask({"command": "expand_set_pos", "pos": 3_000_001, "speed": 100},
                        "expand_set_pos")["set_pos_state"] is False
        peer.close()
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(10) == 0

"""ArmClient against the simulator over real loopback TCP."""
from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from rm65_driver.protocol import messages as P
from rm65_driver.protocol.arm_client import ArmClient, ArmCommandError, ArmConnectionError, ArmStopped, ArmTimeout
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator
from rm65_testing import HOME_DEG, wait_for

HOME = np.radians(HOME_DEG)


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_connect_to_nothing_fails_fast_with_a_connection_error():
    c = ArmClient("127.0.0.1", _free_port(), connect_timeout_s=0.5)
    t0 = time.monotonic()
    with pytest.raises(ArmConnectionError, match="cannot connect"):
        c.connect()
    assert time.monotonic() - t0 < 1.0
    assert not c.connected
    with pytest.raises(ArmConnectionError, match="not connected"):
        c.get_state()


def test_a_controller_that_hangs_up_is_a_connection_error(sim):
    sim.refuse_connections()
    c = ArmClient("127.0.0.1", sim.port, connect_timeout_s=0.5, reply_timeout_s=0.5)
    with pytest.raises(ArmConnectionError):
        c.connect()


def test_reconnect_backs_off_until_the_controller_accepts(sim):
    sim.refuse_connections(3)
    c = ArmClient("127.0.0.1", sim.port, connect_timeout_s=0.5, reply_timeout_s=0.5, backoff_s=(0.02, 0.1))
    t0 = time.monotonic()
    c.reconnect(deadline_s=3.0)
    dt = time.monotonic() - t0
    assert c.connected and 0.02 + 0.04 + 0.08 <= dt < 2.0  # three back-off waits, doubling
    c.close()
    sim.refuse_connections()
    with pytest.raises(ArmConnectionError, match="gave up"):
        c.reconnect(deadline_s=0.3)


@pytest.mark.parametrize("fmt", ["list", "scalar", "arm_sys"])
@pytest.mark.parametrize("pretty", [False, True])
def test_state_in_every_error_format_and_pretty_replies(fmt, pretty):
    config = SimulatorConfig(err_format=fmt, pretty_replies=pretty, initial_joints_deg=HOME_DEG)
    with ArmSimulator(port=0, config=config) as s:
        with ArmClient("127.0.0.1", s.port) as c:
            c.connect()
            st = c.get_state()
            np.testing.assert_allclose(st.joints_rad, HOME, atol=1e-5)
            assert st.error_codes == () and st.err_format == fmt
            s.set_error(0x100D)
            assert c.get_state().errors_text == ["0x100D: collision detected"]


def test_moves_wait_for_arrival(client, sim):
    q = np.radians([10, -35, -95, 5, -50, 20])
    client.move_joints_and_wait(q, 50, timeout_s=5)
    np.testing.assert_allclose(sim.joints, q, atol=2e-5)
    pose = client.get_state().pose
    pose[2] -= 0.03
    client.move_linear_and_wait(pose, 20, timeout_s=5)
    np.testing.assert_allclose(client.get_state().pose[:3], pose[:3], atol=2e-6)
    pose[0] += 0.03
    client.move_pose_and_wait(pose, 20, timeout_s=5)
    np.testing.assert_allclose(client.get_state().pose[:3], pose[:3], atol=2e-6)
    assert [n for n in sim.command_names() if n.startswith("move")] == ["movej", "movel", "movej_p"]


def test_refused_and_failed_motions_raise_decoded_controller_errors(client, sim):
    with pytest.raises(ArmCommandError) as e:
        client.move_joints_and_wait(np.radians([0, 0, 170, 0, 0, 0]), 20)
    assert e.value.code == 0x1002 and "exceeds the joint limit" in e.value.text
    with pytest.raises(ArmCommandError) as e:
        client.move_pose_and_wait([0.9, 0, 0.1, np.pi, 0, 0], 20)
    assert e.value.code == 0x1003
    sim.fail_next("movej", 0x100D, mode="trajectory")
    with pytest.raises(ArmCommandError) as e:
        client.move_joints_and_wait(np.radians([20, -30, -100, 0, -50, 0]), 50)
    assert e.value.code == 0x100D and "collision" in str(e.value)
    sim.fail_next("set_DO_state", 0x2005)
    with pytest.raises(ArmCommandError, match="0x2005"):
        client.set_do(1, True)


def test_stalled_motion_times_out(client, sim):
    sim.stall_next_motion()
    with pytest.raises(ArmTimeout):
        client.move_joints_and_wait(np.radians([20, -30, -100, 0, -50, 0]), 50, timeout_s=0.3)
    assert client.current_trajectory() == "movej"
    client.stop()
    client.wait_idle(1.0)


def test_connection_drop_mid_motion_raises_then_reconnect_and_wait_idle(client, sim):
    sim.drop_mid_motion(fraction=0.3)
    with pytest.raises(ArmConnectionError, match="connection lost"):
        client.move_joints_and_wait(np.radians([30, -30, -100, 0, -50, 0]), 20, timeout_s=5)
    assert not client.connected
    client.reconnect(2.0)
    client.wait_idle(5.0)
    np.testing.assert_allclose(np.degrees(client.get_state().joints_rad)[0], 30, atol=1e-3)


def test_estop_reaches_the_controller_within_100ms_while_a_motion_is_awaited(client, sim):
    # Real-time motion so the wait is genuinely long; another thread is also blocked on a
    # request whose reply never comes (both must not delay the stop).
    sim.time_scale = 1.0
    errors: list[BaseException] = []

    def mover():
        try:
            client.move_joints_and_wait(np.radians([90, -30, -100, 0, -50, 0]), 5, timeout_s=30)
        except BaseException as exc:  # noqa: BLE001 - handed to the test thread
            errors.append(exc)

    def stuck_query():
        try:
            client.request({"command": "get_joint_degree"}, timeout_s=1.0)
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)

    sim.fail_next("get_joint_degree", 0, mode="no_reply")
    threads = [threading.Thread(target=mover), threading.Thread(target=stuck_query)]
    for t in threads:
        t.start()
    assert wait_for(lambda: sim.moving and sim.joints[0] > 0.001, 2.0)
    assert wait_for(lambda: "get_joint_degree" in sim.command_names(), 2.0)
    latencies = []
    for _ in range(5):
        t0 = time.monotonic()
        client.stop(wait_reply=False)
        assert wait_for(lambda: len(sim.commands_named("set_arm_stop")) > len(latencies), 1.0, period=0.0005)
        latencies.append(sim.commands_named("set_arm_stop")[-1].t - t0)
    threads[0].join(2.0)
    assert not threads[0].is_alive()
    assert isinstance(errors[0], ArmStopped)
    assert not sim.moving
    worst = max(latencies)
    print(f"\ne-stop latency (client.stop() -> decoded at the controller): "
          f"median {np.median(latencies) * 1e3:.2f} ms, max {worst * 1e3:.2f} ms over {len(latencies)} stops")
    # no wall-clock limit here (flaky on a shared 2-core machine): bench/bench_arm_latency.py measures it
    threads[1].join(5.0)


def test_a_stop_before_the_motion_is_sent_prevents_it(client, sim):
    epoch = client.stop_count
    client.stop()
    n = len(sim.motion_log)
    with pytest.raises(ArmStopped):
        client.move_joints_and_wait(np.radians([20, -30, -100, 0, -50, 0]), 50, stop_count=epoch)
    assert len(sim.motion_log) == n


def test_pause_does_not_consume_the_motion_timeout(client, sim):
    done = threading.Event()
    errors: list[BaseException] = []

    def mover():
        try:
            client.move_joints_and_wait(np.radians([15, -30, -100, 0, -50, 0]), 50, timeout_s=0.5)
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)
        done.set()

    sim.time_scale = 0.3  # 15 deg at 90 deg/s = 0.17 s sim -> ~0.05 s real
    client.pause()  # pause first so the motion is held from its start
    t = threading.Thread(target=mover)
    t.start()
    time.sleep(0.7)  # longer than the 0.5 s budget
    assert not done.is_set()
    client.resume()
    assert done.wait(2.0) and not errors
    t.join()


def test_concurrent_requests_from_many_threads_get_their_own_replies(client, sim):
    results: list[object] = []

    def worker(i):
        for _ in range(20):
            if i % 2:
                results.append(client.get_state().joints_rad.shape)
            else:
                results.append(client.get_do(1))

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    client.move_joints_and_wait(np.radians([5, -30, -100, 0, -50, 0]), 50)
    for t in threads:
        t.join()
    assert len(results) == 80 and set(results) <= {(6,), 0}


def test_io_and_frames(client, sim):
    client.set_io_output_mode(2)
    client.set_do(2, True)
    assert client.get_do(2) == 1 and sim.do_state(2) == 1
    client.set_do(2, False)
    client.set_io_output_mode(1, tool=True)
    client.set_do(1, True, tool=True)
    assert client.get_do(1, tool=True) == 1
    client.set_tool_frame("weld_gun", [0, 0, 0.15, 0, 0, 0], payload_kg=1.2)
    assert client.current_tool_frame()[0] == "weld_gun"
    name, pose = client.current_work_frame()
    assert name == "Base" and np.allclose(pose, 0)
    with pytest.raises(ArmCommandError):
        client.set_work_frame("missing")


def test_controller_info_runs_the_sdk_handshake(client):
    info = client.controller_info()
    assert set(info) == set(P.HANDSHAKE_COMMANDS)
    assert info["get_arm_software_info"]["Product_version"] == "RM65-BI"
    assert all(v is not None for v in info.values())


def test_a_connected_line_runs_as_one_trajectory_and_reports_its_handover(client, sim):
    q = np.radians([10, -35, -95, 5, -50, 20])
    client.move_joints_and_wait(q, 50, timeout_s=5)
    start = client.get_state().pose
    short, contact = start.copy(), start.copy()
    short[2] -= 0.04
    contact[2] -= 0.05
    handovers: list[tuple[int, np.ndarray]] = []
    client.move_linear_path_and_wait([(short, 30), (contact, 10)], timeout_s=5,
                                     on_handover=lambda i: handovers.append((i, sim.tcp_pose()[:3, 3].copy())))
    np.testing.assert_allclose(client.get_state().pose[:3], contact[:3], atol=2e-6)
    sent = sim.commands_named("movel")[-2:]
    assert [(c.msg["v"], c.msg["trajectory_connect"]) for c in sent] == [(30, 1), (10, 0)]
    # the hand-over came when the first line ended: at (or just past) the short standoff
    assert [i for i, _ in handovers] == [1]
    assert np.linalg.norm(handovers[0][1] - short[:3]) < 0.004


def test_a_refused_second_segment_leaves_nothing_to_run(client, sim):
    q = np.radians([10, -35, -95, 5, -50, 20])
    client.move_joints_and_wait(q, 50, timeout_s=5)
    start = client.get_state().pose
    short = start.copy()
    short[2] -= 0.02
    with pytest.raises(ArmCommandError) as e:
        client.move_linear_path_and_wait([(short, 30), ([0.9, 0, 0.1, np.pi, 0, 0], 10)], timeout_s=5)
    assert e.value.code == 0x1003
    time.sleep(0.2)  # the first segment, acknowledged and held, was dropped by a stop: the arm never moved
    np.testing.assert_allclose(sim.joints, q, atol=2e-5)
    assert not sim.moving
    client.move_linear_and_wait(short, 30, timeout_s=5)  # and the next motion runs normally
    np.testing.assert_allclose(client.get_state().pose[:3], short[:3], atol=2e-6)


def test_a_motion_sent_to_be_connected_waits_for_the_next_one(sim):
    raw = socket.create_connection(("127.0.0.1", sim.port))
    q0 = sim.joints.copy()
    raw.sendall(P.encode(P.movej(q0 + np.radians([20, 0, 0, 0, 0, 0]), 50, trajectory_connect=1)))
    time.sleep(0.3)
    np.testing.assert_allclose(sim.joints, q0, atol=1e-9)  # planned, not executed
    raw.sendall(P.encode(P.movej(q0, 50)))  # the next one: now both run, and the arm comes back
    assert wait_for(lambda: not sim.moving, 5.0)
    np.testing.assert_allclose(sim.joints, q0, atol=2e-5)
    assert len(sim.commands_named("movej")) == 2
    raw.close()


def test_a_controller_that_says_all_done_after_the_first_segment_is_not_believed_until_the_arm_is_still():
    config = SimulatorConfig(time_scale=0.3, initial_joints_deg=HOME_DEG, report_connected=False)
    with ArmSimulator(port=0, config=config) as s:
        c = ArmClient("127.0.0.1", s.port, connect_timeout_s=1.0, reply_timeout_s=1.0)
        c.connect()
        c.move_joints_and_wait(np.radians([10, -35, -95, 5, -50, 20]), 50, timeout_s=5)
        short, contact = c.get_state().pose, c.get_state().pose
        short[2] -= 0.03
        contact[2] -= 0.04
        c.move_linear_path_and_wait([(short, 30), (contact, 10)], timeout_s=5)
        # returned only at the contact, never at the short standoff where the first "all done" came
        assert not s.moving
        np.testing.assert_allclose(s.tcp_pose()[:3, 3], contact[:3], atol=2e-6)
        c.close()

"""The official RealMan SDK (PyPI robotic-arm 1.1.6) connects to our simulator and drives it.

The SDK is a ctypes wrapper around a bundled native library that can crash the interpreter on
a bad reply, so it runs in a child process; the test is skipped when the SDK is not installed.
"""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("Robotic_Arm") is None,
                                reason="official SDK robotic-arm not installed")

SDK_SCRIPT = textwrap.dedent("""
    import json, sys
    from Robotic_Arm.rm_robot_interface import RoboticArm, rm_thread_mode_e
    port = int(sys.argv[1])
    arm = RoboticArm(rm_thread_mode_e.RM_SINGLE_MODE_E)
    handle = arm.rm_create_robot_arm("127.0.0.1", port, level=3)
    out = {"handle": handle.id}
    out["state"] = arm.rm_get_current_arm_state()
    out["movej"] = arm.rm_movej([5, -30, -95, 0, -55, 0], 50, 0, 0, 1)
    out["state2"] = arm.rm_get_current_arm_state()
    out["movel"] = arm.rm_movel([0.28, 0.0, 0.15, 3.142, 0.0, 0.0], 20, 0, 0, 1)
    out["refused"] = arm.rm_movej([0, 0, 179, 0, 0, 0], 20, 0, 0, 1)
    out["io"] = [arm.rm_set_io_mode(1, 1), arm.rm_set_do_state(1, 1)]
    out["stop"] = arm.rm_set_arm_stop()
    arm.rm_delete_robot_arm()
    print("RESULT " + json.dumps(out))
""")


def test_official_sdk_connects_and_reads_the_arm_state(sim):
    proc = subprocess.run([sys.executable, "-c", SDK_SCRIPT, str(sim.port)], capture_output=True, text=True,
                          timeout=30)
    lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    assert lines, f"SDK run failed (rc {proc.returncode}): {proc.stdout[-800:]} {proc.stderr[-800:]}"
    out = json.loads(lines[-1][len("RESULT "):])
    assert out["handle"] == 1  # handshake accepted (id -1 on a failed handshake)
    ret, state = out["state"]
    assert ret == 0
    np.testing.assert_allclose(state["joint"], [0, -30, -100, 0, -50, 0], atol=1e-3)
    np.testing.assert_allclose(state["pose"][:3], sim.kin.fk(np.radians([0, -30, -100, 0, -50, 0]))[:3, 3], atol=2e-6)
    assert out["movej"] == 0 and out["state2"][0] == 0
    np.testing.assert_allclose(out["state2"][1]["joint"], [5, -30, -95, 0, -55, 0], atol=1e-3)
    assert out["movel"] == 0
    assert out["refused"] == 1  # the SDK's "controller refused" code
    assert out["io"] == [0, 0] and sim.do_state(1) == 1
    assert out["stop"] == 0
    names = sim.command_names()
    assert names[:11] == ["get_arm_software_info", "get_arm_current_trajectory", "get_realtime_push",
                          "get_current_work_frame", "get_current_tool_frame", "get_install_pose",
                          "get_joint_min_pos", "get_joint_max_pos", "get_joint_max_acc", "get_joint_max_speed",
                          "get_DH_data"]


SDK_RAIL_SCRIPT = textwrap.dedent("""
    import json, sys, time
    from Robotic_Arm.rm_robot_interface import RoboticArm, rm_thread_mode_e
    port = int(sys.argv[1])
    arm = RoboticArm(rm_thread_mode_e.RM_SINGLE_MODE_E)
    handle = arm.rm_create_robot_arm("127.0.0.1", port, level=3)
    out = {"handle": handle.id}
    out["state0"] = arm.rm_get_expand_state()
    out["blocking"] = arm.rm_set_expand_pos(50, 1500000, 20)   # single-thread mode: block = timeout in s
    out["state1"] = arm.rm_get_expand_state()
    out["refused"] = arm.rm_set_expand_pos(50, 7000000, 0)     # beyond the 6 m travel
    out["nonblocking"] = arm.rm_set_expand_pos(30, 500000, 0)
    out["moving"] = arm.rm_get_expand_state()
    states = []
    for _ in range(400):
        ret, st = arm.rm_get_expand_state()
        states.append(st["mode"])
        if st["mode"] == 0:
            break
        time.sleep(0.02)
    out["state2"] = arm.rm_get_expand_state()
    out["modes"] = states
    out["jog"] = [arm.rm_set_expand_speed(40), arm.rm_set_expand_speed(0)]
    arm.rm_delete_robot_arm()
    print("RESULT " + json.dumps(out))
""")


def test_official_sdk_drives_the_expansion_joint_position_state_and_arrival():
    from rm65_driver.rail.axis import RailAxis
    from rm65_sim.config import SimulatorConfig
    from rm65_sim.simulator import ArmSimulator
    from rm65_testing import HOME_DEG

    config = SimulatorConfig(time_scale=0.1, initial_joints_deg=HOME_DEG, rail_axis=RailAxis(6.0))
    sim = ArmSimulator(port=0, config=config).start()
    try:
        proc = subprocess.run([sys.executable, "-c", SDK_RAIL_SCRIPT, str(sim.port)], capture_output=True,
                              text=True, timeout=60)
    finally:
        sim.stop()
    lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    assert lines, f"SDK run failed (rc {proc.returncode}): {proc.stdout[-800:]} {proc.stderr[-800:]}"
    out = json.loads(lines[-1][len("RESULT "):])
    assert out["handle"] == 1
    assert out["state0"] == [0, {"pos": 0, "current": 0, "err_flag": 0, "mode": 0}]
    assert out["blocking"] == 0  # returned on the device-4 arrival
    assert out["state1"][0] == 0 and out["state1"][1]["pos"] == 1_500_000 and out["state1"][1]["mode"] == 0
    assert out["refused"] == 1  # the SDK's "controller refused"
    assert out["nonblocking"] == 0
    ret, moving = out["moving"]
    assert ret == 0 and moving["mode"] == 4 and 500_000 < moving["pos"] <= 1_500_000  # toward -, started or on its way
    assert out["state2"][1] == {"pos": 500_000, "current": 0, "err_flag": 0, "mode": 0}
    assert set(out["modes"][:-1]) == {4}
    assert out["jog"] == [0, 0]
    sent = [c.msg for c in sim.commands if c.name == "expand_set_pos"]
    assert sent[0] == {"command": "expand_set_pos", "speed": 50, "pos": 1500000, "block": True}
    assert [ok for _, ok in sim.rail.arrivals] == [True, True]

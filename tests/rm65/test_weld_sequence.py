"""WeldSequence end to end against the simulator: jobs, rejections, errors, drops, stops."""
from __future__ import annotations

import errno
import json
import os
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import RM65Kinematics
from rm65_driver.protocol import messages as P
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
from rm65_driver.weld.weld_job import StudTarget, WeldParams
from rm65_driver.weld.weld_sequence import WeldSequence
from rm65_sim.config import SimulatorConfig
from rm65_sim.simulator import ArmSimulator
from rm65_testing import FAST, dome_targets, wait_for, welds_per_stud
from stud_common.vocabulary import OnDisconnect, StudOrder

PARAMS = WeldParams(standoff_m=0.04, tool_offset_m=0.15, pulse_s=0.01, dwell_s=0.01, joint_speed_pct=50,
                    linear_speed_pct=20, motion_timeout_s=5.0, reconnect_timeout_s=3.0)


def make_seq(client, tmp_path, params=PARAMS, phases=None, **limits):
    journal = Journal(tmp_path / "weld.jsonl")
    safety = SafetyChecker(RM65Kinematics(), SafetyLimits(**limits), params.tool_T)
    cb = (lambda *a: phases.append(a)) if phases is not None else None
    return WeldSequence(client, journal, safety, params, on_phase=cb), journal


def test_full_dome_job_welds_every_stud_once_on_its_normal(client, sim, tmp_path):
    targets = dome_targets()
    assert len(targets) == 20
    phases: list = []
    seq, journal = make_seq(client, tmp_path, phases=phases)
    t0 = time.monotonic()
    res = seq.run(targets)
    dt = time.monotonic() - t0
    print(f"\nweld job: {len(targets)} studs in {dt:.2f} s wall (simulator time_scale 0.02, "
          f"pulse {PARAMS.pulse_s} s, dwell {PARAMS.dwell_s} s)")
    assert res.success, res.message
    assert res.welded == [t.stud_id for t in targets] and not res.skipped and not res.failed
    assert set(welds_per_stud(sim, targets).values()) == {1}
    for edge, t in zip(sim.rising_edges(1), targets):
        np.testing.assert_allclose(edge.position, t.position, atol=1e-4)
        assert np.degrees(np.arccos(np.clip(edge.tcp_pose[:3, 2] @ -t.normal, -1, 1))) < 0.2
    assert sim.do_state(1) == 0
    assert journal.welded_ids == {t.stud_id for t in targets} and not journal.uncertain_ids
    first = [p[1] for p in phases if p[0] == "S0000"]
    assert first == ["approach", "descend", "weld", "dwell", "retract"]
    assert phases[-1][3] == 20
    # resume: nothing is welded twice
    res2 = seq.run(targets, resume=True)
    assert res2.success and res2.welded == res.welded
    res3 = seq.run(targets, resume=False)
    assert res3.skipped == res.welded and all("already welded" in m for m in res3.messages)
    assert len(sim.rising_edges(1)) == 20


def test_rejected_targets_are_never_sent(client, sim, tmp_path):
    good = dome_targets(rings=((0.0, 1), (0.05, 2)))
    unreachable = StudTarget("FAR", [0.50, 0.0, 0.0], [0, 0, 1])
    # beyond the cell's gun tilt (60 deg from vertical by default): not the stud's 5 deg lean budget
    tilted = StudTarget("TILT", [0.30, 0.08, 0.0], [np.sin(np.radians(70)), 0, np.cos(np.radians(70))])
    outside = StudTarget("LOW", [0.30, -0.08, -0.05], [0, 0, 1])
    targets = [good[0], unreachable, good[1], tilted, outside, good[2]]
    seq, journal = make_seq(client, tmp_path)
    res = seq.run(targets)
    assert res.success and res.welded == [good[0].stud_id, good[1].stud_id, good[2].stud_id]
    assert res.skipped == ["FAR", "TILT", "LOW"]
    msgs = dict(m.split(": ", 1) for m in res.messages)
    assert "unreachable" in msgs["FAR"] and "tilt 70.0 deg" in msgs["TILT"] and "workspace box" in msgs["LOW"]
    assert journal.status("FAR") == "skipped"
    # the simulator never saw a motion towards a rejected stud
    movels = [P.pose_from_wire(c.msg["pose"])[:3] for c in sim.commands_named("movel")]
    for bad in (unreachable, tilted, outside):
        assert min(np.linalg.norm(np.array(movels) - bad.position, axis=1)) > 0.06
    assert len(sim.commands_named("movej")) == 3
    assert set(welds_per_stud(sim, good).values()) == {1}


def test_controller_error_mid_job_aborts_with_the_decoded_error_and_a_clean_journal(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 4)))
    sim.fail_next("movel", 0x100D, mode="trajectory", nth=5)  # descend of the third stud
    seq, journal = make_seq(client, tmp_path)
    res = seq.run(targets)
    assert not res.success
    assert "0x100D: collision detected" in res.message
    assert res.welded == ["S0000", "S0001"] and res.failed == ["S0002"]
    assert journal.welded_ids == {"S0000", "S0001"} and not journal.uncertain_ids
    assert sum(1 for m in res.messages if "not processed" in m) == 2
    lines = (tmp_path / "weld.jsonl").read_text().splitlines()
    assert all(json.loads(x)["stud"] in {"S0000", "S0001"} for x in lines)
    assert not sim.moving and sim.do_state(1) == 0


def test_trigger_refused_after_start_leaves_the_stud_uncertain(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 2)))
    sim.fail_next("set_DO_state", 0x2005, nth=4)  # prepare sets low once, S0000 high+low, then S0001 high
    seq, journal = make_seq(client, tmp_path)
    res = seq.run(targets)
    assert not res.success and "0x2005" in res.message
    assert res.welded == ["S0000"] and res.failed == ["S0001"]
    assert journal.uncertain_ids == {"S0001"}
    assert sim.do_state(1) == 0


def test_connection_drop_mid_descend_reconnects_and_no_stud_is_welded_twice_or_skipped(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 7)))
    sim.drop_mid_motion(nth=3, fraction=0.5, command="movel")  # S0001's descent
    sim.drop_mid_motion(nth=7, fraction=0.2, command="movej")  # a later approach (counted from now)
    seq, journal = make_seq(client, tmp_path)
    res = seq.run(targets)
    assert res.success, res.message
    assert res.welded == [t.stud_id for t in targets] and not res.skipped and not res.failed
    assert set(welds_per_stud(sim, targets).values()) == {1}
    assert sim.connection_count == 3  # two drops, two reconnects


def test_connection_drop_after_the_trigger_marks_the_stud_uncertain_and_the_job_goes_on(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 5)))
    sim.drop_after_commands(4, command="set_DO_state")  # prepare: low; S0000: high, low; S0001: high -> drop
    seq, journal = make_seq(client, tmp_path)
    res = seq.run(targets)
    assert res.failed == ["S0001"] and "uncertain" in res.messages[0]
    assert res.welded == ["S0000", "S0002", "S0003", "S0004", "S0005"]
    counts = welds_per_stud(sim, targets)
    assert set(counts.values()) == {1}  # S0001 fired once (then the link dropped) and never again
    assert journal.uncertain_ids == {"S0001"}
    assert sim.do_state(1) == 0  # forced low after the reconnect
    # Next job: the uncertain stud is refused until an operator decides
    res2 = seq.run(targets)
    assert res2.failed == ["S0001"] and len(sim.rising_edges(1)) == 6
    journal.resolve("S0001", welded=True, note="stud present")
    res3 = seq.run(targets)
    assert res3.success and len(res3.welded) == 6 and len(sim.rising_edges(1)) == 6


def test_on_disconnect_abort_policy(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 3)))
    sim.drop_after_commands(2, command="set_DO_state")  # prepare low, S0000 high -> drop
    params = WeldParams(**{**PARAMS.__dict__, "on_disconnect": "abort"})
    seq, journal = make_seq(client, tmp_path, params=params)
    res = seq.run(targets)
    assert not res.success and "on_disconnect=abort" in res.message
    assert res.failed == ["S0000"] and len(sim.rising_edges(1)) == 1


def test_reconnect_failure_aborts_the_job(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 2)))
    params = WeldParams(**{**PARAMS.__dict__, "reconnect_timeout_s": 0.3})
    seq, journal = make_seq(client, tmp_path, params=params)
    sim.refuse_connections()  # the open connection lives on; any new one is refused
    sim.drop_mid_motion(nth=3, fraction=0.5, command="movel")  # S0001's descent
    t0 = time.monotonic()
    res = seq.run(targets)
    assert time.monotonic() - t0 < 3.0
    assert not res.success and "not recovered" in res.message and "gave up reconnecting" in res.message
    assert res.welded == ["S0000"] and not res.failed  # S0001 was never triggered
    assert journal.welded_ids == {"S0000"} and not journal.uncertain_ids


def test_cancel_during_approach_stops_the_arm_and_welds_nothing_more(client, sim, tmp_path):
    sim.time_scale = 0.3
    targets = dome_targets(rings=((0.0, 1), (0.05, 3)))
    seq, journal = make_seq(client, tmp_path)
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("res", seq.run(targets)))
    t.start()
    assert wait_for(lambda: seq.current_stud == "S0001" and seq.phase == "approach" and sim.moving, 10)
    seq.cancel()
    t.join(10)
    res = out["res"]
    assert res.message == "cancelled" and res.welded == ["S0000"] and not res.failed
    assert "set_arm_stop" in sim.command_names()
    assert len(sim.rising_edges(1)) == 1 and not journal.uncertain_ids
    assert not sim.moving


def test_cancel_after_the_trigger_completes_the_stud(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 3)))
    params = WeldParams(**{**PARAMS.__dict__, "dwell_s": 0.3})
    seq, journal = make_seq(client, tmp_path, params=params)
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("res", seq.run(targets)))
    t.start()
    assert wait_for(lambda: seq.current_stud == "S0000" and seq.phase == "dwell", 10)
    seq.cancel()
    t.join(10)
    res = out["res"]
    assert res.message == "cancelled" and res.welded == ["S0000"]
    assert journal.welded_ids == {"S0000"}
    np.testing.assert_allclose(sim.tcp_pose()[:3, 3], targets[0].position + 0.04 * targets[0].normal, atol=1e-4)


def test_halt_during_dwell_stops_at_once_and_leaves_the_stud_uncertain(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 3)))
    params = WeldParams(**{**PARAMS.__dict__, "pulse_s": 0.5})
    seq, journal = make_seq(client, tmp_path, params=params)
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("res", seq.run(targets)))
    t.start()
    assert wait_for(lambda: sim.do_state(1) == 1, 10)
    seq.halt("e-stop")
    t.join(10)
    assert not t.is_alive()  # ended by the halt (its latency: bench/bench_arm_latency.py, not a unit-test limit)
    res = out["res"]
    assert res.message == "halted: e-stop" and res.failed == ["S0000"]
    assert journal.uncertain_ids == {"S0000"} and sim.do_state(1) == 0
    assert sim.command_names()[-1] in ("set_DO_state", "set_arm_stop")


def test_pause_and_resume_mid_job(client, sim, tmp_path):
    sim.time_scale = 0.2
    targets = dome_targets(rings=((0.0, 1), (0.05, 1)))
    seq, journal = make_seq(client, tmp_path)
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("res", seq.run(targets)))
    t.start()
    assert wait_for(lambda: seq.current_stud == "S0001" and sim.moving, 10)
    seq.pause()
    q = sim.joints
    time.sleep(0.2)
    np.testing.assert_allclose(sim.joints, q)
    seq.resume()
    t.join(10)
    assert out["res"].success and len(sim.rising_edges(1)) == 2


def test_job_refused_for_speed_caps_and_a_foreign_work_frame(client, sim, tmp_path):
    fast = WeldParams(**{**PARAMS.__dict__, "linear_speed_pct": 60})
    seq, _ = make_seq(client, tmp_path, params=fast)
    res = seq.run(dome_targets())
    assert not res.success and "speed cap" in res.message and not sim.commands_named("movej")
    client.command(P.set_manual_work_frame("table", [0.3, 0, 0, 0, 0, 0]))
    client.set_work_frame("table")
    seq2, _ = make_seq(client, tmp_path)
    res = seq2.run(dome_targets())
    assert not res.success and "not the base frame" in res.message
    with pytest.raises(ValueError):
        WeldParams(on_disconnect="retry")
    # the modes arrive as text (ROS parameters) and are held as the vocabulary's members
    modes = WeldParams(stud_order="path", on_disconnect="abort")
    assert modes.stud_order is StudOrder.PATH and modes.on_disconnect is OnDisconnect.ABORT


@pytest.mark.parametrize("standoff_m, stud_length_m, ok", [
    (0.05, 0.0, True),     # the stud's height not known: not checked
    (0.06, 0.05, True),    # 50 mm stud, 10 mm clearance
    (0.059, 0.05, False),  # the gun's foot 9 mm over the stud's top
    (0.05, 0.05, False),   # on the stud's top: the sideways move would drag the gun over it
    (0.08, 0.08, False),
])
def test_the_retract_must_pull_the_gun_off_the_whole_welded_stud(standoff_m, stud_length_m, ok):
    if ok:
        WeldParams(standoff_m=standoff_m, stud_length_m=stud_length_m)
        return
    with pytest.raises(ValueError, match=r"does not pull the gun off the welded stud.*standoff_m >= "):
        WeldParams(standoff_m=standoff_m, stud_length_m=stud_length_m)


def test_controller_restart_mid_pulse_sets_the_controller_up_again_and_the_job_goes_on(client, sim, tmp_path):
    """The controller restarts (a new simulator on the same port) while the trigger is high: the new
    one comes up with its IO in input mode and the factory tool frame. The job reconnects, sets
    both again, leaves the cut-off stud uncertain (never re-welded) and welds the rest."""
    targets = dome_targets(rings=((0.0, 1), (0.05, 4)))
    params = WeldParams(**{**PARAMS.__dict__, "pulse_s": 0.3})
    seq, journal = make_seq(client, tmp_path, params=params)
    out = {}
    job = threading.Thread(target=lambda: out.setdefault("res", seq.run(targets)))
    job.start()
    sims = [sim]
    try:
        assert sim.wait_until(lambda: len(sim.rising_edges(1)) == 2 and sim.do_state(1) == 1, 20)  # S0001 firing
        q = sim.joints
        sim.stop()
        config = SimulatorConfig(time_scale=FAST, initial_joints_deg=np.degrees(q))
        restarted = ArmSimulator(port=sim.port, config=config).start()
        sims.append(restarted)
        job.join(30)
        res = out["res"]
        assert res.welded == ["S0000", "S0002", "S0003", "S0004"], res.message
        assert res.failed == ["S0001"] and "uncertain" in res.messages[0]
        assert journal.uncertain_ids == {"S0001"}
        counts = {t.stud_id: sum(welds_per_stud(s, targets)[t.stud_id] for s in sims) for t in targets}
        assert counts == {t.stud_id: 1 for t in targets}  # the cut-off stud fired once, before the restart
        names = restarted.command_names()
        assert names.index("set_IO_mode") < names.index("set_DO_state")  # output mode before driving it low
        assert "set_manual_tool_frame" in names and restarted.do_state(1) == 0
    finally:
        for s in sims:
            s.stop()


@pytest.mark.parametrize("record, uncertain", [("started", False), ("welded", True)])
def test_a_journal_write_that_fails_stops_the_job_before_its_next_motion(client, sim, tmp_path, monkeypatch, record,
                                                                          uncertain):
    targets = dome_targets(rings=((0.0, 1), (0.05, 3)))
    seq, journal = make_seq(client, tmp_path)
    real_write = os.write
    at_failure = {}

    def disk_full(fd, data):
        if f'"event":"{record}","stud":"S0001"'.encode() in bytes(data):
            at_failure["commands"] = len(sim.commands)
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", disk_full)
    res = seq.run(targets)
    assert not res.success and res.welded == ["S0000"] and res.failed == ["S0001"]
    assert "No space left on device" in res.message and "weld.jsonl" in res.message
    after = [c.name for c in sim.commands[at_failure["commands"]:]]
    assert not set(after) & {"movej", "movel", "movej_p"}, after  # nothing moved after the failed write
    assert len(sim.rising_edges(1)) == (2 if uncertain else 1) and sim.do_state(1) == 0
    assert journal.status("S0001") == ("uncertain" if uncertain else "new")
    # the journal refuses to go on until it is opened again (the driver's FAULT): no new job moves
    monkeypatch.setattr(os, "write", real_write)
    n = len(sim.commands_named("movej"))
    res2 = seq.run(targets)
    assert "job refused" in res2.message and "failed earlier" in res2.message
    assert len(sim.commands_named("movej")) == n


def test_every_journal_record_of_a_job_carries_its_job_id(client, sim, tmp_path):
    seq, journal = make_seq(client, tmp_path)
    res = seq.run(dome_targets(rings=((0.0, 1), (0.05, 1))))
    res2 = seq.run([StudTarget("FAR", [0.50, 0.0, 0.0], [0, 0, 1])])
    recs = [json.loads(x) for x in (tmp_path / "weld.jsonl").read_text().splitlines()]
    assert res.job_id and res2.job_id != res.job_id
    assert [r["job"] for r in recs] == [res.job_id] * 4 + [res2.job_id]


@settings(max_examples=10, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(slope=st.floats(0.0, 35.0), side=st.sampled_from([-1.0, 1.0]), turn=st.floats(-30.0, 30.0),
       x=st.floats(0.26, 0.32), y=st.floats(-0.06, 0.06))
def test_studs_on_any_slope_up_to_35_deg_are_welded_with_the_gun_along_their_normal(client, sim, tmp_path, slope,
                                                                                   side, turn, x, y):
    """The gun follows the normal whatever the slope: every stud the arm reaches is welded, the gun's
    axis at the weld (forward kinematics of the simulator's joints at the trigger's rising edge)
    within 1 deg of the normal. (Slopes facing across the arm's reach: one facing straight away from
    or toward the base folds or stretches the RM-65 out of reach at 35 deg -- refused as unreachable,
    tested in test_safety.)"""
    az = np.radians(90.0 * side + turn) + np.arctan2(y, x)
    s = np.radians(slope)
    n = np.array([np.sin(s) * np.cos(az), np.sin(s) * np.sin(az), np.cos(s)])
    target = StudTarget(f"T{len(sim.rising_edges(1))}", [x, y, 0.04], n)
    seq, _journal = make_seq(client, tmp_path / f"{slope:.3f}_{x:.3f}_{y:.3f}_{side}")
    before = len(sim.rising_edges(1))
    res = seq.run([target])
    assert res.welded == [target.stud_id], res.messages
    edge = sim.rising_edges(1)[before]
    axis = edge.tcp_pose[:3, 2]  # the tool's z: the gun, pointing into the part
    assert np.degrees(np.arccos(np.clip(axis @ -n, -1.0, 1.0))) < 1.0
    np.testing.assert_allclose(edge.position, target.position, atol=1e-4)


# -- the cycle: fast approach to a short standoff, the slow final move, the studs' order -------------------
FAST_CYCLE = WeldParams(standoff_m=0.05, tool_offset_m=0.15, pulse_s=0.01, dwell_s=0.01, joint_speed_pct=50,
                        linear_speed_pct=10, approach_speed_pct=30, final_approach_m=0.01, stud_order="tour",
                        motion_timeout_s=5.0, reconnect_timeout_s=3.0)


def _linear_moves(sim):
    return [(P.pose_from_wire(c.msg["pose"])[:3], c.msg["v"]) for c in sim.commands_named("movel")]


def test_fast_approach_stops_short_and_the_last_stretch_is_slow(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 3)))
    seq, journal = make_seq(client, tmp_path, params=FAST_CYCLE)
    res = seq.run(targets)
    assert res.success, res.message
    assert set(welds_per_stud(sim, targets).values()) == {1}
    by_stud = {t.stud_id: t for t in targets}
    moves = _linear_moves(sim)
    assert len(moves) == 3 * len(targets)  # fast approach, slow final move, retract
    order = [r["stud"] for r in (json.loads(x) for x in (tmp_path / "weld.jsonl").read_text().splitlines())
             if r["event"] == "started"]
    for k, sid in enumerate(order):
        t = by_stud[sid]
        (p_short, v_fast), (p_contact, v_slow), (p_back, v_back) = moves[3 * k: 3 * k + 3]
        np.testing.assert_allclose(p_short, t.position + 0.01 * t.normal, atol=1e-5)  # the short standoff
        np.testing.assert_allclose(p_contact, t.position, atol=1e-5)
        np.testing.assert_allclose(p_back, t.position + 0.05 * t.normal, atol=1e-5)  # clear of the stud again
        assert (v_fast, v_slow, v_back) == (30, 10, 30)  # the contact is always approached at the slow speed
    started = [json.loads(x) for x in (tmp_path / "weld.jsonl").read_text().splitlines()]
    motion = [r["motion_s"] for r in started if r["event"] == "started"]
    assert all(set(m) == {"move", "approach", "descend"} and min(m.values()) > 0 for m in motion)
    assert not any("rail_position_m" in r for r in started)  # a fixed arm's journal: no carriage


def test_a_connected_approach_goes_on_to_the_slow_final_move_without_a_stop_and_welds_at_the_contact(
        client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 3)))
    phases: list = []
    seq, journal = make_seq(client, tmp_path, params=replace(FAST_CYCLE, connected_approach=True), phases=phases)
    res = seq.run(targets)
    assert res.success, res.message
    assert set(welds_per_stud(sim, targets).values()) == {1}  # each trigger at its stud's contact pose
    moves = sim.commands_named("movel")
    assert len(moves) == 3 * len(targets)
    flags = [(c.msg["v"], c.msg["trajectory_connect"]) for c in moves]
    assert flags == [(30, 1), (10, 0), (30, 0)] * len(targets)  # approach -> final move joined; retract alone
    by_stud = {t.stud_id: t for t in targets}
    started = [json.loads(x) for x in (tmp_path / "weld.jsonl").read_text().splitlines()]
    for r in (r for r in started if r["event"] == "started"):
        assert set(r["motion_s"]) == {"move", "approach", "descend"} and min(r["motion_s"].values()) > 0
        seen = [ph for sid, ph, *_ in phases if sid == r["stud"]]
        assert seen[:3] == ["approach", "descend", "weld"], seen
        t = by_stud[r["stud"]]
        np.testing.assert_allclose(r["position"], t.position, atol=1e-9)


def test_a_cancel_during_the_connected_approach_backs_out_and_welds_nothing_more(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 2)))
    phases: list = []
    seq, journal = make_seq(client, tmp_path, params=replace(FAST_CYCLE, connected_approach=True), phases=phases)
    sim.stall_next_motion(fraction=0.5, command="movel")  # the first stud's fast approach freezes half-way
    out: dict = {}
    th = threading.Thread(target=lambda: out.setdefault("res", seq.run(targets)))
    th.start()
    assert wait_for(lambda: any(ph == "approach" for _, ph, *_ in phases) and sim.moving, 5.0)
    time.sleep(0.1)
    seq.cancel()
    th.join(10)
    res = out["res"]
    assert not res.success and "cancelled" in res.message
    assert not sim.rising_edges(1)  # nothing triggered
    assert not any(json.loads(x)["event"] == "started" for x in (tmp_path / "weld.jsonl").read_text().splitlines())
    back = _linear_moves(sim)[-1]
    assert back[1] == FAST_CYCLE.linear_speed_pct  # the back-out: slow, straight out along the normal
    assert any(np.allclose(back[0], t.position + 0.05 * t.normal, atol=1e-5) for t in targets)


def test_a_fast_approach_above_the_speed_cap_is_refused_before_anything_moves(client, sim, tmp_path):
    params = replace(FAST_CYCLE, approach_speed_pct=40)
    seq, _journal = make_seq(client, tmp_path, params=params, max_linear_speed_pct=30)
    res = seq.run(dome_targets(rings=((0.0, 1),)))
    assert not res.success and "linear speed 40 % outside 1..30 %" in res.message
    assert not sim.commands_named("movej") and not sim.commands_named("movel")


def test_studs_are_welded_along_a_short_joint_path_each_once_and_reported_in_request_order(client, sim, tmp_path):
    ring = dome_targets(rings=((0.10, 10),))
    shuffled = [ring[k] for k in (0, 5, 1, 6, 2, 7, 3, 8, 4, 9)]  # across the ring and back, every time
    seq, journal = make_seq(client, tmp_path, params=FAST_CYCLE)
    res = seq.run(shuffled)
    assert res.success, res.message
    assert res.welded == [t.stud_id for t in shuffled]
    assert set(welds_per_stud(sim, shuffled).values()) == {1}
    joints = np.array([q for kind, q in sim.motion_log if kind == "movej"])
    travel = np.sum(np.max(np.abs(np.diff(joints, axis=0)), axis=1))
    # the given order crosses the ring each time: its approach joints travel far more
    (tmp_path / "given").mkdir()
    given_seq, _ = make_seq(client, tmp_path / "given", params=replace(FAST_CYCLE, stud_order="given"))
    n_before = len(sim.motion_log)
    assert given_seq.run(shuffled).success
    given = np.array([q for kind, q in sim.motion_log[n_before:] if kind == "movej"])
    assert travel < 0.7 * np.sum(np.max(np.abs(np.diff(given, axis=0)), axis=1))


def test_a_drop_during_the_fast_approach_backs_out_along_the_normal_and_welds_the_stud_once(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 2)))
    sim.drop_mid_motion(nth=1, fraction=0.5, command="movel")  # the first stud's fast approach
    seq, journal = make_seq(client, tmp_path, params=FAST_CYCLE)
    res = seq.run(targets)
    assert res.success, res.message
    assert set(welds_per_stud(sim, targets).values()) == {1}
    first = [r for r in (json.loads(x) for x in (tmp_path / "weld.jsonl").read_text().splitlines())][0]["stud"]
    t = {x.stud_id: x for x in targets}[first]
    moves = _linear_moves(sim)
    # after the reconnect: straight back out to the standoff before the stud is approached again
    np.testing.assert_allclose(moves[1][0], t.position + 0.05 * t.normal, atol=1e-5)


def test_each_next_stud_is_planned_during_the_dwell_not_between_the_studs(client, sim, tmp_path):
    targets = dome_targets(rings=((0.0, 1), (0.05, 4)))
    seq, journal = make_seq(client, tmp_path)
    phases_at_check = []
    check_target = seq.safety.check_target

    def counted(*args, **kwargs):
        phases_at_check.append(seq.phase)
        return check_target(*args, **kwargs)
    seq.safety.check_target = counted  # type: ignore[method-assign]
    res = seq.run(targets)
    assert res.success and sorted(res.welded) == sorted(t.stud_id for t in targets)
    assert set(welds_per_stud(sim, targets).values()) == {1}
    # one plan a stud: the first before it, every other one during the dwell of the stud before it
    assert len(phases_at_check) == len(targets) and phases_at_check[1:] == ["dwell"] * (len(targets) - 1)
    assert seq.plans_ahead_used == len(targets) - 1


def test_a_plan_made_ahead_is_used_only_for_its_stud_and_from_where_the_arm_is(client, sim, tmp_path):
    from rm65_driver.weld.stud_cycle import LOOKAHEAD_TOL_RAD

    seq, _ = make_seq(client, tmp_path)
    lookahead = seq.cycle.lookahead
    t, other = dome_targets(rings=((0.05, 2),))
    q = np.radians([0.0, 20.0, 70.0, 0.0, 90.0, 0.0])
    lookahead.plan(t, q)
    assert lookahead.planned is not None
    assert lookahead.take(other, q) is None and lookahead.planned is None  # another stud came next
    lookahead.plan(t, q)
    assert lookahead.take(t, q + 2 * LOOKAHEAD_TOL_RAD) is None  # the arm is elsewhere: planned again
    lookahead.plan(t, q)
    ahead = lookahead.take(t, q + 0.5 * LOOKAHEAD_TOL_RAD)
    assert ahead is not None and ahead.ok
    now = seq.safety.check_target(t.position, t.normal, PARAMS.standoff_m, q, PARAMS.plunge_m).plan
    assert ahead.plan is not None and now is not None and ahead.plan.yaw_rad == now.yaw_rad
    np.testing.assert_allclose(ahead.plan.q_approach, now.q_approach)
    np.testing.assert_allclose(ahead.plan.q_contact, now.q_contact)
    assert lookahead.take(t, q) is None  # used once
    # the joint move is checked again from where the arm is: a plan whose move from there leaves the
    # workspace is not used
    lookahead.plan(t, q)
    seq.safety.check_joint_path = lambda *a, **k: "approach move: outside the workspace box"  # type: ignore
    assert lookahead.take(t, q) is None

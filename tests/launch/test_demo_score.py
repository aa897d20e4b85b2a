"""The demo's judgement (stud_bringup.demo_score): the gun's true pose at each weld rebuilt from the weld
journal on a rail with a simulated error, the accuracy at both ends of a long part, and the registrations,
rail moves and job span read from a real MCAP cell bag."""
from __future__ import annotations

import json

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from stud_welding_msgs.msg import ArmState, CellStatus, Registration

from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import RM65Kinematics
from stud_bag import BagWriter
from stud_bringup.demo_score import (
    accuracy_at_ends,
    cell_bag_summary,
    job_span_s,
    rail_moves,
    registrations,
    score,
    welds_from_journal,
)
from stud_common import names
from stud_common.frames import RailDeviation, true_world_correction, world_T_base
from stud_perception.scene import girder_scene, surface_height, surface_normal
from stud_perception.scene_file import scene_to_dict

KIN = RM65Kinematics()
TOOL_OFFSET_M = 0.15
MOUNT = (0.0, 0.0, 0.2)
DEVIATION = RailDeviation(scale_ppm=1000.0, offset_m=0.0005, yaw_urad_per_m=50.0)
HOME = np.radians([0.0, -30.0, -100.0, 0.0, -50.0, 0.0])


def tool_T() -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = TOOL_OFFSET_M
    return T


def contact_pose(point_w, normal_w, W: np.ndarray) -> np.ndarray:
    """The weld tool at ``point_w`` (world, as the cell believes it) along -normal, in the base frame."""
    z = -np.asarray(normal_w, float) / np.linalg.norm(normal_w)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = point_w
    return np.linalg.inv(W) @ T


def weld_as_the_driver(journal: Journal, sid: str, point_w, normal_w, carriage_m: float) -> np.ndarray:
    """Journal a weld the way the driver does: joints solved for the target in the base frame of a carriage
    at ``carriage_m`` on the believed rail, ``rail_position_m`` with them."""
    res = KIN.ik(contact_pose(point_w, normal_w, world_T_base(carriage_m, MOUNT)), HOME, tool=tool_T())
    assert res.success, res.message
    journal.started(sid, job="j", position=list(point_w), normal=list(normal_w), joints=res.q.tolist(),
                    joints_at_weld=res.q.tolist(), rail_position_m=carriage_m)
    journal.welded(sid, job="j")
    return res.q


def girder_truth(k: int):
    scene = girder_scene(start_xy_m=(0.5, 0.3), stud_spacing_m=0.08)
    xy = scene.studs_world_xy_m[k]
    p = np.array([*xy, float(surface_height(scene, xy[:1], xy[1:])[0])])
    return scene, p, np.asarray(surface_normal(scene, xy[:1], xy[1:])).reshape(3)


def test_the_gun_is_scored_where_the_rail_truly_carried_it_not_where_the_cell_believes(tmp_path):
    # The cell registers on marks seen from the carriage at c: its targets are in the believed world, the true
    # stud moved by the inverse of the rail's error there; the gun goes to the target and truly lands on the stud.
    scene, _, _ = girder_truth(0)
    report, journal = {"targets": []}, Journal(tmp_path / "weld.jsonl")
    for k in (0, len(scene.stud_ids) - 2):  # a stud at each end of the girder
        sid = scene.stud_ids[k]
        _, p_true, n_true = girder_truth(k)
        c = float(p_true[0]) - 0.05
        C_inv = np.linalg.inv(true_world_correction(c, DEVIATION))
        target = C_inv[:3, :3] @ p_true + C_inv[:3, 3]
        normal = C_inv[:3, :3] @ n_true
        weld_as_the_driver(journal, sid, target, normal, c)
        report["targets"].append({"stud_id": sid, "position_m": target.tolist(), "normal": normal.tolist(),
                                  "welded": True})
    journal.close()
    scene_file = tmp_path / "girder.json"
    scene_file.write_text(json.dumps(scene_to_dict(scene)))

    welds = welds_from_journal(tmp_path / "weld.jsonl", TOOL_OFFSET_M, MOUNT, DEVIATION)
    assert set(welds) == {t["stud_id"] for t in report["targets"]}
    acc = score(report, scene_file, welds=welds)
    assert all(r["from_weld"] for r in acc["studs"])
    assert acc["max_xy_error_mm"] < 0.01 and acc["max_z_error_mm"] < 0.01 and acc["max_gun_axis_error_deg"] < 0.01, acc
    # judged on the believed rail instead (the deviation ignored) the far stud is millimetres off: what the
    # registration per carriage position corrected
    believed = score(report, scene_file, welds=welds_from_journal(tmp_path / "weld.jsonl", TOOL_OFFSET_M, MOUNT))
    far = max(believed["studs"], key=lambda r: r["x_m"])
    assert far["xy_error_m"] > 0.005, far
    # and the cell's own targets against the truth say the same (what the fixed arm's score compared)
    assert score(report, scene_file)["max_xy_error_mm"] > 5.0


def test_a_fixed_arms_journal_is_the_forward_kinematics_of_its_joints_and_the_plunge_is_backed_off(tmp_path):
    journal = Journal(tmp_path / "weld.jsonl")
    p, n = np.array([0.25, 0.02, 0.10]), np.array([0.0, -0.2, 1.0]) / np.hypot(0.2, 1.0)
    plunge = 0.003
    res = KIN.ik(contact_pose(p - plunge * n, n, np.eye(4)), HOME, tool=tool_T())
    journal.started("S1", job="j", joints_at_weld=res.q.tolist())       # no rail: no rail_position_m
    journal.started("S2", job="j", joints_at_weld=res.q.tolist())       # started, never welded: not a weld
    journal.welded("S1", job="j")
    journal.close()
    welds = welds_from_journal(tmp_path / "weld.jsonl")
    assert list(welds) == ["S1"] and welds["S1"].rail_position_m == 0.0
    np.testing.assert_allclose(welds["S1"].tip_w, p - plunge * n, atol=1e-6)
    np.testing.assert_allclose(welds["S1"].axis_w, -n, atol=1e-6)
    assert welds_from_journal(tmp_path / "missing.jsonl") == {}


def test_accuracy_at_the_ends_takes_the_studs_near_each_end_only():
    rows = [{"x_m": x, "xy_error_m": e, "z_error_m": e / 2, "normal_error_deg": 0.1, "slope_deg": 2.5, "welded": True,
             "gun_axis_error_deg": 0.2}
            for x, e in ((0.5, 0.0002), (0.8, 0.0003), (3.0, 0.009), (6.2, 0.0007), (6.4, 0.0004))]
    ends = accuracy_at_ends(rows, span_m=0.5)
    assert ends["start"]["studs"] == 2 and ends["start"]["max_xy_error_mm"] == pytest.approx(0.3)
    assert ends["far_end"]["studs"] == 2 and ends["far_end"]["max_xy_error_mm"] == pytest.approx(0.7)
    assert ends["far_end"]["x_m"] == [6.2, 6.4]


def _stamp(t_s: float) -> Time:
    return Time(sec=int(t_s), nanosec=int(round((t_s % 1) * 1e9)))


def _state(t_s: float, rail_m: float, moving: bool) -> ArmState:
    m = ArmState(rail_position_m=rail_m, rail_moving=moving)
    m.header.stamp = _stamp(t_s)
    return m


def _registration(t_s: float, marks: list[str], rms_m: float, max_m: float, extrapolated_m: float = 0.0,
                  valid: bool = True) -> Registration:
    m = Registration(valid=valid, labels_used=marks, residual=rms_m, residual_max=max_m,
                     extrapolated_distance=extrapolated_m)
    m.header.stamp = _stamp(t_s)
    return m


def _status(t_s: float, state: str) -> CellStatus:
    m = CellStatus(state_text=state)
    m.header.stamp = _stamp(t_s)
    return m


def test_registrations_rail_moves_and_the_job_span_come_from_a_recorded_cell_bag(tmp_path):
    states = [_state(100.0, 0.0, False), _state(101.0, 0.3, True), _state(102.0, 0.315, False),
              _state(110.0, 0.315, False), _state(111.0, 0.5, True), _state(112.5, 0.614, False),
              _state(120.0, 0.6145, False),  # within the tolerance: the same stop
              _state(121.0, 0.8, True), _state(122.0, 0.935, False)]
    regs = [_registration(103.0, ["O", "A", "B"], 1e-5, 2e-5), _registration(104.0, [], 0.0, 0.0, valid=False),
            _registration(113.0, ["A", "M1", "M2", "M3"], 4e-5, 8e-5),
            _registration(123.0, ["M5"], 4e-5, 8e-5, extrapolated_m=0.32)]
    statuses = [_status(99.0, "idle"), _status(102.5, "registering"), _status(105.0, "welding"),
                _status(125.0, "done"), _status(126.0, "idle")]
    bag = tmp_path / "cell_bag"
    with BagWriter(bag) as w:
        for topic, type_name, msgs in ((names.ARM_STATE, "stud_welding_msgs/msg/ArmState", states),
                                       (names.REGISTRATION_RESULT, "stud_welding_msgs/msg/Registration", regs),
                                       (names.CELL_STATUS, "stud_welding_msgs/msg/CellStatus", statuses)):
            w.add_topic(topic, type_name)
            for m in msgs:
                t_ns = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                w.write(topic, m, t_ns)
    got = cell_bag_summary(bag)
    assert got["rail"] == rail_moves(states)
    assert got["rail"]["moves"] == 3 and got["rail"]["stops_m"] == [0.0, 0.315, 0.614, 0.935]
    assert got["rail"]["distance_m"] == pytest.approx(0.935)
    assert got["registrations"] == registrations(regs, states) and got["registrations_invalid"] == 1
    assert [r["carriage_m"] for r in got["registrations"]] == [0.315, 0.614, 0.935]
    assert got["registrations"][1]["marks"] == ["A", "M1", "M2", "M3"]
    assert got["registrations"][1]["residual_max_mm"] == pytest.approx(0.08)
    assert got["registrations"][2]["extrapolated_m"] == pytest.approx(0.32)
    assert got["job_s"] == job_span_s(statuses) == pytest.approx(22.5)
    assert cell_bag_summary(tmp_path / "no_bag") == {"registrations": [], "registrations_invalid": 0,
                                                     "rail": {"moves": 0, "distance_m": 0.0, "stops_m": []},
                                                     "job_s": None}


"""A weld job on a rail: it works in the arm's base frame, its journal and cell limits in world, so studs
welded from one carriage position stand where they are for a job from another."""
from __future__ import annotations

import json

import numpy as np

from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import RM65Kinematics
from rm65_driver.rail.control import target_in_base
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
from rm65_driver.weld.weld_job import StudTarget, WeldParams
from rm65_driver.weld.weld_sequence import WeldSequence
from stud_common.frames import world_T_base

PARAMS = WeldParams(standoff_m=0.06, tool_offset_m=0.15, pulse_s=0.01, dwell_s=0.01, joint_speed_pct=50,
                    linear_speed_pct=20, motion_timeout_s=5.0, min_stud_spacing_m=0.035, stud_length_m=0.05)
MOUNT = (0.0, 0.0, 0.05)
LIMITS = SafetyLimits(workspace_min_m=(-0.7, -0.7, -0.02), workspace_max_m=(6.7, 0.7, 1.2))


def job(client, journal, carriage_m):
    W = world_T_base(carriage_m, MOUNT)
    seq = WeldSequence(client, journal, SafetyChecker(RM65Kinematics(), LIMITS, PARAMS.tool_T, W), PARAMS)
    seq.cycle.rail_position_m = carriage_m  # as the driver sets it on a rail
    return seq, W


def test_a_stud_welded_from_one_carriage_position_blocks_its_neighbour_welded_from_another(client, sim, tmp_path):
    journal = Journal(tmp_path / "weld.jsonl")
    a = StudTarget("A", [1.30, 0.0, 0.03], [0, 0, 1])  # world
    b = StudTarget("B", [1.32, 0.0, 0.03], [0, 0, 1])  # 20 mm from A, in world
    c = StudTarget("C", [1.40, 0.0, 0.03], [0, 0, 1])  # 100 mm: room for the gun
    seq1, W1 = job(client, journal, 1.0)
    res = seq1.run([target_in_base(a, W1)])
    assert res.success and res.welded == ["A"], res.message
    [edge] = sim.rising_edges(1)
    np.testing.assert_allclose(edge.position, [0.30, 0.0, -0.02], atol=1e-4)  # in the base frame, 1 m back
    started = [json.loads(x) for x in (tmp_path / "weld.jsonl").read_text().splitlines() if '"started"' in x]
    np.testing.assert_allclose(started[0]["position"], a.position, atol=1e-12)  # the journal: world
    # ... with the carriage: the weld's world pose is the carriage's base times the joints' forward kinematics
    assert started[0]["rail_position_m"] == 1.0
    T = W1 @ RM65Kinematics().fk(np.asarray(started[0]["joints_at_weld"])) @ PARAMS.tool_T
    np.testing.assert_allclose(T[:3, 3], a.position, atol=1e-4)
    seq2, W2 = job(client, journal, 1.1)  # the carriage moved on by 0.1 m
    res = seq2.run([target_in_base(b, W2), target_in_base(c, W2)])
    assert res.skipped == ["B"] and res.welded == ["C"], res.messages
    assert "welded stud A stands 20 mm from the gun foot's axis" in res.messages[0]


def test_the_workspace_box_is_checked_in_world(client, sim, tmp_path):
    journal = Journal(tmp_path / "weld.jsonl")
    seq, W = job(client, journal, 6.5)  # near the end of the rail
    beyond = StudTarget("END", [6.80, 0.0, 0.03], [0, 0, 1])  # reachable from the base, outside the box (world)
    res = seq.run([target_in_base(beyond, W)])
    assert res.skipped == ["END"] and "leaves the workspace box at (6.800" in res.messages[0]
    assert not sim.rising_edges(1)

"""Welded studs as obstacles: the geometry (segments, pure) and the weld job refusing a stud whose gun
foot would hit a neighbour already welded, over real TCP to the arm simulator."""
from __future__ import annotations

import numpy as np
import pytest

from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import RM65Kinematics
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits
from rm65_driver.weld.weld_job import WeldParams
from rm65_driver.weld.weld_sequence import WeldSequence
from rm65_driver.weld.welded_neighbours import nearest_welded, segment_distances
from rm65_testing import dome_targets, welds_per_stud


def _brute(a0, a1, b0, b1):
    s = np.linspace(0.0, 1.0, 401)
    P, Q = a0 + s[:, None] * (a1 - a0), b0 + s[:, None] * (b1 - b0)
    return float(np.min(np.linalg.norm(P[:, None] - Q[None], axis=2)))


def test_segment_distances_are_the_closest_points_of_segments_and_points():
    rng = np.random.default_rng(2)
    for k in range(60):
        a0, a1, b0, b1 = rng.normal(size=(4, 3))
        if k % 5 == 0:
            a1 = a0.copy()  # a point
        if k % 7 == 0:
            b1 = b0.copy()
        if k % 11 == 0:
            b1 = b0 + 0.5 * (a1 - a0)  # parallel
        got = float(segment_distances(a0, a1, b0[None], b1[None])[0])
        assert got <= _brute(a0, a1, b0, b1) + 1e-12
        assert got == pytest.approx(_brute(a0, a1, b0, b1), abs=5e-3)


@pytest.mark.parametrize("lean_deg, closer", [(15.0, True), (-15.0, False)])
def test_the_tops_count_where_studs_lean_together(lean_deg, closer):
    """Two studs 45 mm apart at the base, 50 mm long: in a trough (normals leaning together) the
    welded stud's top comes nearer the gun's foot than its base, on a dome it leans away."""
    a = np.radians(lean_deg)
    welded = [("W", np.zeros(3), np.array([np.sin(a), 0.0, np.cos(a)]))]
    near = nearest_welded(np.array([0.045, 0.0, 0.0]), np.array([-np.sin(a), 0.0, np.cos(a)]), welded,
                          stud_length_m=0.05, clearance_m=0.01)
    assert near is not None and near.stud_id == "W"
    assert (near.distance_m < 0.045 - 0.01) if closer else near.distance_m == pytest.approx(0.045, abs=1e-9)
    assert nearest_welded(np.zeros(3), np.array([0, 0, 1.0]), [], 0.05, 0.01) is None


def test_a_stud_too_close_to_a_welded_one_is_refused_and_never_triggered(client, sim, tmp_path):
    """The dome's ring of 7 studs 43 mm apart, 50 mm from the centre stud, with a gun foot that needs
    45 mm: in the given order every stud next to a welded one is skipped with that neighbour named,
    every other stud is welded once, and no trigger fires at a skipped one."""
    targets = dome_targets(rings=((0.0, 1), (0.05, 7)))
    params = WeldParams(standoff_m=0.06, stud_length_m=0.05, tool_offset_m=0.15, pulse_s=0.01, dwell_s=0.01,
                        joint_speed_pct=50, linear_speed_pct=20, motion_timeout_s=5.0, min_stud_spacing_m=0.045)
    journal = Journal(tmp_path / "weld.jsonl")
    seq = WeldSequence(client, journal, SafetyChecker(RM65Kinematics(), SafetyLimits(), params.tool_T), params)
    res = seq.run(targets)
    # What the rule gives, from the bases alone (the normals here are within 3 deg of each other).
    welded: list = []
    for t in targets:
        if all(np.linalg.norm(t.position - w.position) >= 0.045 for w in welded):
            welded.append(t)
    assert res.welded == [t.stud_id for t in welded]
    assert 0 < len(res.skipped) == len(targets) - len(welded)
    for sid, msg in zip(res.skipped, [m for m in res.messages if "welded stud" in m]):
        assert msg.startswith(f"{sid}: welded stud S") and "min_stud_spacing_m" in msg
    counts = welds_per_stud(sim, targets)
    assert all(counts[t.stud_id] == (1 if t in welded else 0) for t in targets)
    assert all(journal.status(sid) == "skipped" for sid in res.skipped)


def test_studs_welded_by_an_earlier_job_are_obstacles_from_the_journal(client, sim, tmp_path):
    """A station's job welds the centre stud; the next job (another station, a restarted driver: the
    journal opened again) has only a ring stud 50 mm away, and the gun's foot needs 52 mm: it is
    refused with the earlier job's stud named, though that stud is in none of this job's targets."""
    centre, ring = dome_targets(rings=((0.0, 1), (0.05, 1)))
    params = WeldParams(standoff_m=0.06, stud_length_m=0.05, tool_offset_m=0.15, pulse_s=0.01, dwell_s=0.01,
                        joint_speed_pct=50, linear_speed_pct=20, motion_timeout_s=5.0, min_stud_spacing_m=0.052)

    def job(targets):
        with Journal(tmp_path / "weld.jsonl") as journal:
            seq = WeldSequence(client, journal, SafetyChecker(RM65Kinematics(), SafetyLimits(), params.tool_T), params)
            return seq.run(targets), journal.standing_studs()

    first, standing = job([centre])
    assert first.welded == [centre.stud_id]
    (sid, pos, normal), = standing  # where the journal says the stud stands: its target, as welded
    assert sid == centre.stud_id and np.allclose(pos, centre.position) and np.allclose(normal, centre.normal)
    second, _ = job([ring])
    assert second.welded == [] and second.skipped == [ring.stud_id], second
    assert second.messages[0].startswith(f"{ring.stud_id}: welded stud {centre.stud_id} stands 50 mm")
    assert welds_per_stud(sim, [centre, ring]) == {centre.stud_id: 1, ring.stud_id: 0}


def test_the_studs_standing_are_the_welded_and_uncertain_ones_with_their_started_points(tmp_path):
    with Journal(tmp_path / "weld.jsonl") as journal:
        for sid, x in (("A", 0.1), ("B", 0.2), ("C", 0.3), ("D", 0.4)):
            journal.started(sid, position=[x, 0.0, 0.01], normal=[0.0, 0.0, 1.0])
        journal.welded("A")
        journal.resolve("C", welded=False, note="no stud there")  # the operator looked: nothing stands
        journal.resolve("D", welded=True)
        journal.skipped("E", "unreachable")
    with Journal(tmp_path / "weld.jsonl") as journal:  # the same, read back from the file
        standing = {sid: pos for sid, pos, _n in journal.standing_studs()}
    assert standing == {"A": (0.1, 0.0, 0.01), "B": (0.2, 0.0, 0.01), "D": (0.4, 0.0, 0.01)}

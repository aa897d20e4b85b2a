"""Cycle-time split: a recorded timeline of cell states and weld phases into seconds per category."""
from __future__ import annotations

import math

import pytest

from stud_cell.cycle_time import CycleEvent, format_split, motion_from_journal, split_cycle


def cell(t, state):
    return CycleEvent(t, "cell", state)


def weld(t, phase, stud):
    return CycleEvent(t, "weld", phase, stud)


TIMELINE = [cell(0.0, "registering"), cell(2.0, "moving"), cell(3.0, "shooting"), cell(3.5, "matching"),
            cell(4.0, "welding"), weld(4.1, "approach", "A"), weld(4.5, "descend", "A"), weld(5.0, "weld", "A"),
            cell(5.1, "welding"),  # a status re-published with new counts: the weld phase goes on
            weld(5.2, "dwell", "A"), weld(5.7, "retract", "A"), weld(6.0, "approach", "B"),
            weld(6.2, "descend", "B"), weld(6.4, "weld", "B"), weld(6.6, "dwell", "B"), weld(7.1, "retract", "B"),
            cell(7.4, "inspecting"), cell(8.4, "done"), cell(9.0, "idle")]


def test_every_second_from_registration_to_done_lands_in_its_category():
    s = split_cycle(TIMELINE, studs=2)
    assert s.total_s == pytest.approx(8.4)
    assert s.seconds["registration"] == pytest.approx(2.0)
    assert s.seconds["station_moves"] == pytest.approx(1.0)
    assert s.seconds["shots"] == pytest.approx(1.0)
    assert s.seconds["weld_overhead"] == pytest.approx(0.1)
    assert s.seconds["moves_between_studs"] == pytest.approx(0.4 + 0.2)  # no motion_s: all of approach
    assert s.seconds["approach"] == 0.0
    assert s.seconds["descent"] == pytest.approx(0.5 + 0.2)
    assert s.seconds["weld"] == pytest.approx(0.2 + 0.2)
    assert s.seconds["dwell"] == pytest.approx(0.5 + 0.5)
    assert s.seconds["retract"] == pytest.approx(0.3 + 0.3)
    assert s.seconds["inspection"] == pytest.approx(1.0)
    assert sum(s.seconds.values()) == pytest.approx(s.total_s)
    assert s.s_per_stud == pytest.approx(4.2) and s.studs_per_hour == pytest.approx(3600 / 4.2)


def test_an_idle_cell_before_its_job_is_not_cycle_time():
    s = split_cycle([cell(-1.3, "idle")] + TIMELINE, studs=2)
    assert s.total_s == pytest.approx(8.4) and sum(s.seconds.values()) == pytest.approx(s.total_s)


def test_the_journal_motion_times_split_the_approach_phase():
    records = [{"event": "started", "stud": "A", "motion_s": {"move": 0.25, "approach": 0.15, "descend": 0.5}},
               {"event": "welded", "stud": "A"}, {"event": "started", "stud": "B"}]
    motion = motion_from_journal(records)
    assert motion == {"A": {"move": 0.25, "approach": 0.15, "descend": 0.5}}
    s = split_cycle(TIMELINE, studs=2, motion_s=motion)
    assert s.seconds["moves_between_studs"] == pytest.approx(0.25 + 0.2)
    assert s.seconds["approach"] == pytest.approx(0.15)
    # a status re-published mid-approach cuts the phase in two: the split is of the whole phase
    cut = sorted(TIMELINE + [cell(4.3, "welding")], key=lambda e: e.t_s)
    s2 = split_cycle(cut, studs=2, motion_s=motion)
    assert s2.seconds["moves_between_studs"] == pytest.approx(0.25 + 0.2)
    assert s2.seconds["approach"] == pytest.approx(0.15)


def test_no_studs_gives_no_rate_and_a_table_still_prints():
    s = split_cycle([cell(0.0, "registering"), cell(1.0, "failed")], studs=0)
    assert s.total_s == pytest.approx(1.0) and math.isnan(s.s_per_stud) and s.studs_per_hour == 0.0
    assert "registration" in format_split(s, "empty")
